"""Taylor impact of an OFHC copper rod on a rigid wall (built-in `taylor_bar`, 2D axisymmetric,
J2 + Johnson-Cook). Reference: Johnson & Cook 1983 (7th Int. Symp. Ballistics), L0 = 25.4 mm,
D0 = 7.62 mm at 190 m/s: measured final length 0.638 L0 = 16.2 mm and footprint diameter
1.78 D0 = 13.6 mm (as tabulated with Zerilli & Armstrong, J. Appl. Phys. 61 (1987) 1816, with
the same rods at 130 and 146 m/s: 0.770 and 0.736 L0).

Code verification (`material="steel_42crmo4"`): a Johnson-Cook 42CrMo4 steel rod, L0 = 32.4 mm,
D0 = 6.4 mm, at 287 m/s on a frictionless rigid wall, computed by two finite element codes
(DynELA's documentation, "DynELA impact sample cases"): final length 26.52 mm (DynELA) and
26.56 mm (Abaqus/Explicit), footprint diameter 11.15 and 11.16 mm.

Copper rod against the widely reproduced computation (`material="copper_bilinear"`): Wilkins &
Guinan's bilinear J2 copper bar, L0 = 32.4 mm, D0 = 6.4 mm, at 227 m/s on a frictionless rigid
wall: at 80 us 21.42 mm long with an impact-face radius of 7.22 mm, converged in mesh size
(Sierra/SolidMechanics and Carina, tabulated in Carina.jl's benchmark/tet15-p1/taylor/README.md;
Foulk et al. 2021)."""

import functools
import re

import jax
import pytest

import jaxmpm
from jaxmpm.scenes.impact import taylor_measures

L_MEASURED, D_MEASURED = 16.2e-3, 13.6e-3
L0 = 25.4e-3
L_OVER_L0_MEASURED = {130.0: 0.770, 146.0: 0.736, 190.0: 0.638}  # Johnson & Cook 1983 via Zerilli & Armstrong 1987


BILINEAR_CONVERGED = (21.42e-3, 7.22e-3)  # (L_f, face radius) in m at 80 us
STEEL_CODES = {"DynELA": (26.52e-3, 11.15e-3), "Abaqus/Explicit": (26.56e-3, 11.16e-3)}  # (L_f, D_f) in m


@functools.lru_cache(maxsize=6)
def run(resolution, speed=None, material="copper_ofhc"):
    scene = jaxmpm.load_scene("taylor_bar", resolution=resolution, speed=speed, material=material)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    final, _ = jaxmpm.simulate(scene, params, s0, progress=False)
    return scene, s0, final


def measured(scene, state):
    """Length and footprint diameter with half a particle spacing added at each free face (the
    particle centres lie that far inside the material's surface)."""
    L, D = taylor_measures(scene, state)
    half = 0.5 * scene.grid.h / scene.phases[0].ppc
    return L + half, D + 2 * half


def energy(s):
    return float(jaxmpm.diagnostics.kinetic_energy(s) + jaxmpm.diagnostics.internal_energy(s))


def test_rod_comes_to_rest_on_the_frictionless_wall_conserving_energy():
    """Resolution 0.5: the rigid slip wall does no work, so the kinetic energy becomes internal
    energy (plastic work and heat) with kinetic + internal conserved (measured 0.04%); at 80 us
    the rod is at rest (kinetic energy 0.9% of the initial) and shorter and wider than it was."""
    scene, s0, final = run(0.5, 190.0)  # the scene's default speed: the run the next test reuses
    assert all(bool(jax.numpy.isfinite(a).all()) for a in jax.tree.leaves(final))
    assert float(final.mass.sum()) == float(s0.mass.sum())
    assert energy(final) == pytest.approx(energy(s0), rel=0.005)
    assert float(jaxmpm.diagnostics.kinetic_energy(final)) < 0.02 * float(jaxmpm.diagnostics.kinetic_energy(s0))
    (L0, D0), (L1, D1) = measured(scene, s0), measured(scene, final)
    assert L1 < 0.8 * L0 and D1 > 1.5 * D0, (L0, L1, D0, D1)


def test_final_length_falls_with_impact_speed_as_measured():
    """The three tests of the same rods (130, 146, 190 m/s), resolution 0.5: the shortening from
    one speed to the next matches the measured one within 5%: L(130) - L(190) = 0.1337 L0 and
    L(146) - L(190) = 0.0989 L0 measured here against 0.132 and 0.098 L0 (0.1326 and 0.0981 at
    resolution 1). The lengths themselves are long by a near-constant 0.034 - 0.045 L0 (about
    1 mm) at every speed: 0.815, 0.780, 0.682 L0 here; 0.809, 0.775, 0.676 at resolution 1."""
    L = {}
    for speed in L_OVER_L0_MEASURED:
        scene, _, final = run(0.5, speed)
        L[speed] = measured(scene, final)[0] / L0
    print("taylor_bar L_f / L0 at 130, 146, 190 m/s:", {k: round(v, 4) for k, v in L.items()})
    for slow in (130.0, 146.0):
        assert L[slow] - L[190.0] == pytest.approx(L_OVER_L0_MEASURED[slow] - L_OVER_L0_MEASURED[190.0], rel=0.05), L


@pytest.mark.slow  # 37 s; the copper bar stays in the default run
def test_johnson_cook_steel_rod_matches_two_finite_element_codes():
    """The verification case at resolution 0.5 (1010 particles): final length within 1% of both
    codes' (measured 26.46 mm against 26.52 and 26.56 mm; 26.44 mm at resolution 1), footprint
    within 5% (11.56 mm against 11.15 and 11.16 mm). Without thermal softening (m = 10) the
    footprint is 10.39 mm and fails; energy is conserved as for the copper rod."""
    scene, s0, final = run(0.5, material="steel_42crmo4")
    assert scene.materials[0].key == "steel_42crmo4" and scene.phases[0].velocity == (0.0, -287.0)
    L, D = measured(scene, final)
    print(f"taylor_bar steel_42crmo4: L_f = {L * 1e3:.2f} mm, footprint {D * 1e3:.2f} mm")
    for code, (L_ref, D_ref) in STEEL_CODES.items():
        assert L == pytest.approx(L_ref, rel=0.01), (code, L, L_ref)
        assert D == pytest.approx(D_ref, rel=0.05), (code, D, D_ref)
    assert energy(final) == pytest.approx(energy(s0), rel=0.005)
    assert float(jaxmpm.diagnostics.kinetic_energy(final)) < 0.02 * float(jaxmpm.diagnostics.kinetic_energy(s0))


@pytest.mark.slow
@pytest.mark.parametrize("resolution", [0.5, 1.0])
def test_bilinear_copper_bar_matches_the_converged_reference(resolution):
    """The copper bar of Wilkins & Guinan at resolution 0.5 (1010 particles) and at the default
    resolution 1 (4040 particles); both in the slow set (18 s and 68 s of a slow day): final
    length within 1% of the converged 21.42 mm (measured 21.52 and 21.45 mm at resolutions 0.5
    and 1; 21.46 mm at 2) and impact-face radius within 2% of 7.22 mm (measured 7.17 and 7.26 mm;
    7.26 mm at 2). Perfectly plastic (B = 0) it ends 20.88 mm long with a 8.38 mm radius and fails
    both; energy is conserved and the bar is at rest."""
    scene, s0, final = run(resolution, material="copper_bilinear")
    assert scene.materials[0].key == "copper_bilinear" and scene.phases[0].velocity == (0.0, -227.0)
    L, D = measured(scene, final)
    print(f"taylor_bar copper_bilinear: L_f = {L * 1e3:.3f} mm, face radius {D / 2 * 1e3:.3f} mm")
    assert L == pytest.approx(BILINEAR_CONVERGED[0], rel=0.01)
    assert D / 2 == pytest.approx(BILINEAR_CONVERGED[1], rel=0.02)
    assert energy(final) == pytest.approx(energy(s0), rel=0.005)
    assert float(jaxmpm.diagnostics.kinetic_energy(final)) < 0.02 * float(jaxmpm.diagnostics.kinetic_energy(s0))


def test_taylor_bar_refuses_an_unknown_material():
    with pytest.raises(
        ValueError,
        match=re.escape("material = 'steel' is invalid: allowed copper_ofhc | steel_42crmo4 | copper_bilinear"),
    ):
        jaxmpm.load_scene("taylor_bar", material="steel")


@pytest.mark.slow
def test_final_shape_converges_in_resolution():
    """Resolutions 0.5 and 1: final length within 1% (measured 17.31 and 17.18 mm; 17.27 mm at
    resolution 2), footprint within 5% (14.30 and 14.57 mm; 14.64 mm at resolution 2)."""
    (sa, _, fa), (sb, _, fb) = run(0.5), run(1.0)
    (La, Da), (Lb, Db) = measured(sa, fa), measured(sb, fb)
    print(f"taylor_bar: L_f = {La * 1e3:.2f}, {Lb * 1e3:.2f} mm; footprint {Da * 1e3:.2f}, {Db * 1e3:.2f} mm")
    assert Lb == pytest.approx(La, rel=0.01)
    assert Db == pytest.approx(Da, rel=0.05)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known limitation, documented in docs/limitations.md (issue 8): "
    "at resolution 1 the rod ends 17.18 mm long, 6.0% longer than "
    "Johnson & Cook's measured 16.2 mm (footprint 14.57 against 13.6 mm on a frictionless wall); "
    "without the strain-rate term (C = 0) it is 16.00 mm; with the rate on the plastic strain "
    "rate (Johnson & Cook's definition) it is the same 17.18 mm; 17.27 mm at resolution 2; "
    "the offset is near-constant over the three measured speeds (+0.039 L0 at 130 and 146 "
    "m/s, +0.038 at 190), while the speed dependence matches to 0.001 L0",
)
def test_final_length_within_5_percent_of_the_experiment():
    scene, _, final = run(1.0)
    L, _ = measured(scene, final)
    assert L == pytest.approx(L_MEASURED, rel=0.05)
