"""The free-surface velocity of a shocked plate, against its exact value (1D, float64).

A planar impact of an al2024 flyer (10 mm) on an al2024 plate (2.21 mm, the debris cloud's) at the
debris cloud's 6.71 km/s. The symmetric impact shocks both to the Hugoniot state u_p = v0 / 2,
p_H = rho0 Us u_p, Us = c0 + s u_p (E1's Mie-Grueneisen reference curve is this Hugoniot). When the
shock reaches the plate's free rear face, a centred release fan takes the face to p = 0; across the
fan the Riemann invariant u - int dp / (rho c) is constant, so the face moves at

    u_fs = u_p + int_{rho_0'}^{rho_H} c(rho) / rho drho      along the isentrope de = p / rho^2 drho

from (rho_H, e_H = u_p^2 / 2) down to p = 0 (at rho_0' < rho0: the shocked material is hot),
c^2 = dp/drho at constant entropy. `exact_free_surface_velocity` integrates it from the model's own
EOS (`jaxmpm.materials.hydro`): 6.895 km/s at 6.71 km/s (2 u_p would be 6.71), 2.006 km/s at 2 km/s.
The plate has 5.5, 11 and 16.6 cells across it (the debris cloud's plate at resolutions 1, 2, 3);
the face's velocity is the slope of the rearmost particle's position over 0.5-1.5 us (the shock
arrives at 0.23 us; the flyer's rear release arrives after 2 us). docs/closure.md has the tables.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.materials import library_material
from jaxmpm.materials.hydro import bulk_sound_speed2, eos_coefficients
from jaxmpm.materials.library import library_constants
from jaxmpm.model.scene import Box, Grid, Phase, Scene

PLATE, FLYER, SPEED = 2.21e-3, 10e-3, 6710.0  # m, m, m/s
DEBRIS_VISCOSITY = (0.5, 2.0)
WINDOW = (0.5e-6, 1.5e-6)  # s: after the shock's arrival at the face, before the flyer's rear release


def exact_free_surface_velocity(v0, key="al2024", steps=4000):
    """(u_fs, u_p, p_H) of a symmetric planar impact at v0 (m/s) of the library's `key` with its
    Mie-Grueneisen EOS: the release isentrope from the Hugoniot state to p = 0, integrated in rho
    by RK4 (`steps` steps from rho_H down to 0.8 rho0; the p = 0 crossing linearly interpolated)."""
    c = library_constants(key, "mie_gruneisen")
    c = {k: jnp.asarray(c[k], jnp.float64) for k in ("rho0", "c0", "s", "gamma0", "a")}
    rho0, up = float(c["rho0"]), v0 / 2
    Us = float(c["c0"]) + float(c["s"]) * up
    rho_h, e_h, p_h = rho0 * Us / (Us - up), up**2 / 2, rho0 * Us * up

    @jax.jit
    def rhs(rho, y):
        A, B = eos_coefficients("mie_gruneisen", c, rho)
        p = A + B * y[0]
        return jnp.stack([p / rho**2, jnp.sqrt(bulk_sound_speed2("mie_gruneisen", c, rho, y[0])) / rho]), p

    @jax.jit
    def pressure(rho, e):
        A, B = eos_coefficients("mie_gruneisen", c, rho)
        return A + B * e

    assert float(pressure(rho_h, e_h)) == pytest.approx(p_h, rel=1e-9)  # the EOS's reference curve is the Hugoniot
    dr = (0.8 * rho0 - rho_h) / steps
    rho, y = rho_h, jnp.array([e_h, 0.0])  # (e, int c / rho drho)
    p = p_h
    for _ in range(steps):
        k1, _ = rhs(rho, y)
        k2, _ = rhs(rho + dr / 2, y + dr / 2 * k1)
        k3, _ = rhs(rho + dr / 2, y + dr / 2 * k2)
        k4, _ = rhs(rho + dr, y + dr * k3)
        y_new = y + dr / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        p_new = float(pressure(rho + dr, y_new[0]))
        if p_new <= 0.0:
            f = p / (p - p_new)
            return up - float(y[1] + f * (y_new[1] - y[1])), up, p_h
        rho, y, p = rho + dr, y_new, p_new
    raise AssertionError("the release isentrope did not reach p = 0")


@pytest.fixture(scope="module")
def exact():
    return exact_free_surface_velocity(SPEED)[0]


def plate_scene(cells_across, model="mie_gruneisen", viscosity=DEBRIS_VISCOSITY, **closure):
    """The flyer (x < 0) at SPEED on the plate (0 < x < PLATE) at rest, 1D, `cells_across` cells
    across the plate, `model` of the library's al2024; `closure` (c_h, fragmentation) if given."""
    h = PLATE / cells_across
    lo, hi = -FLYER - 2 * h, PLATE + 1.1 * SPEED * WINDOW[1] + 4 * h
    al = library_material("al2024", model)
    return Scene(
        grid=Grid(cells=(int(np.ceil((hi - lo) / h)),), h=h, origin=(lo,)),
        materials=(al,),
        phases=(
            Phase("flyer", "al2024", Box((-FLYER,), (0.0,)), velocity=(SPEED,)),
            Phase("plate", "al2024", Box((0.0,), (PLATE,))),
        ),
        artificial_viscosity=viscosity,
        cfl=0.3,
        t_end=WINDOW[1],
        n_out=30,
        **closure,
    )


def free_surface_velocity(scene):
    """m/s: the slope of the rearmost particle's position over WINDOW."""
    params = jaxmpm.default_params(scene)
    _, hist = jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), progress=False)
    t = np.asarray(hist.t)
    x = np.asarray(hist.x[:, :, 0]).max(axis=1)
    w = (t >= WINDOW[0] * (1 - 1e-9)) & (t <= WINDOW[1] * (1 + 1e-9))
    return float(np.polyfit(t[w], x[w], 1)[0])


def test_the_exact_free_surface_velocity_doubles_the_particle_velocity_in_a_weak_shock():
    """The integrator's check: at 2 km/s (p_H 18.6 GPa) the release nearly retraces the Hugoniot, so
    u_fs is 2 u_p within 0.5% (measured 2006 m/s, +0.3%); at 6.71 km/s the hot release adds 2.8%."""
    u_fs, up, _ = exact_free_surface_velocity(2000.0, steps=1000)
    assert u_fs == pytest.approx(2 * up, rel=0.005)
    assert u_fs > 2 * up
    u_fs, up, p_h = exact_free_surface_velocity(SPEED)
    assert p_h == pytest.approx(91.7e9, rel=0.001)
    assert 1.02 < u_fs / (2 * up) < 1.04  # 6895 m/s


def test_a_shocked_plate_free_surface_converges_to_the_exact_release(exact):
    """The hydrodynamic plate (Mie-Grueneisen, no strength), the debris cloud's viscosity: the face
    moves within 3% of the exact u_fs with 5.5 cells across the plate (the debris cloud's at
    resolution 1) and within 1.5% with 16.6 (resolution 3), the error falling (measured +2.58%,
    +1.87%, +1.37% with 5.5, 11, 16.6 cells: from above, about first order). No deficit: the debris
    cloud's slow front (docs/closure.md) is not the plate's shock and release."""
    errors = np.array([free_surface_velocity(plate_scene(n)) / exact - 1 for n in (5.5, 16.6)])
    print("relative errors of u_fs at 5.5, 16.6 cells:", errors)
    assert 0 < errors[0] < 0.03
    assert abs(errors[1]) < 0.015
    assert abs(errors[1]) < abs(errors[0])


@pytest.mark.slow
def test_a_shocked_plate_free_surface_converges_at_33_and_66_cells(exact):
    """The slow sibling: 33 and 66 cells across the plate, errors +0.69% and +0.25% (measured):
    within 0.5% at 66 cells, and the error more than halves from 33 to 66 cells."""
    errors = np.array([free_surface_velocity(plate_scene(n)) / exact - 1 for n in (33.15, 66.3)])
    print("relative errors of u_fs at 33, 66 cells:", errors)
    assert abs(errors[-1]) < 0.005
    assert abs(errors[1]) < 0.5 * abs(errors[0])


@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="material that carries no tension (failed: p >= 0 and no deviator; the tensile closure's "
    "fragments) keeps the particle-velocity noise of the 'musl' update behind the shock as it reaches "
    "the face: the spalled rear flies above the exact u_fs and does not converge (failed: +9.4% at 16.6 "
    "cells, +7.9% at 66; tensile: +6.0%, +3.8%; +24% / +19% with the viscosity (0.2, 1.0), +4.6% / "
    "+1.4% with (1.0, 4.0); with 'apic' +1.7% / +0.6%): docs/closure.md",
)
@pytest.mark.parametrize(
    "model, closure",
    [
        (None, {}),  # the library's full al2024: spall and Johnson-Cook failure (debris_cloud 'failed')
        ("mie_gruneisen+johnson_cook_thermal", dict(c_h=0.02, fragmentation="tensile")),  # debris_cloud 'tensile'
    ],
    ids=["failed", "tensile"],
)
def test_a_fragmenting_plate_free_surface_is_not_faster_than_the_exact_release(exact, model, closure):
    """The debris cloud's own materials, 16.6 cells across the plate: a spalled rear face may fly
    slower than u_fs (it is released to p = 0 at most), never faster; within 2% of it."""
    u = free_surface_velocity(plate_scene(16.6, model, **closure))
    assert u == pytest.approx(exact, rel=0.02)
