"""Boundary conditions per face: a slip wall takes only normal momentum, a fixed wall takes all,
a separating wall takes only the momentum into it."""

import dataclasses

import numpy as np
import pytest

import jaxmpm
from jaxmpm.model.scene import Boundary, Box, Grid, Phase, Scene

MAT = jaxmpm.Material.make("m", "linear_elastic", rho0=1000.0, E=1e6, nu=0.3)


def _run(kind, side="lo", gravity=None):
    floor = (0.0, 0.3) if side == "lo" else (0.7, 1.0)
    scene = Scene(
        grid=Grid(cells=(20, 20), h=0.05),
        materials=(MAT,),
        phases=(Phase("block", "m", Box((0.3, floor[0]), (0.7, floor[1])), velocity=(2.0, 0.0)),),
        gravity=(0.0, -9.81 if side == "lo" else 9.81) if gravity is None else gravity,
        boundary=Boundary(faces=((f"y_{side}", kind),)),
        t_end=0.05,
        n_out=1,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    final, _ = jaxmpm.simulate(scene, params, s0, progress=False)
    return scene, s0, final


@pytest.mark.parametrize("kind", ["slip", "separating"])
@pytest.mark.parametrize("side", ["lo", "hi"])
def test_slip_wall_keeps_tangential_momentum_and_holds_the_block(side, kind):
    scene, s0, final = _run(kind, side)
    p0, p1 = jaxmpm.diagnostics.momentum(s0), jaxmpm.diagnostics.momentum(final)
    np.testing.assert_allclose(float(p1[0]), float(p0[0]), rtol=1e-12)
    drop = abs(float(np.average(final.x[:, 1], weights=final.mass) - np.average(s0.x[:, 1], weights=s0.mass)))
    assert drop < 0.1 * 0.5 * 9.81 * 0.05**2  # held: the centre of mass moves < 10% of free fall
    wall, inward = (0.0, 1.0) if side == "lo" else (1.0, -1.0)
    assert np.all((np.asarray(final.x[:, 1]) - wall) * inward > 0.0)  # no particle on or past the wall


def test_fixed_wall_takes_tangential_momentum_free_face_does_not():
    _, s0, fixed = _run("fixed")
    _, _, free = _run("free")
    p0 = float(jaxmpm.diagnostics.momentum(s0)[0])
    assert float(jaxmpm.diagnostics.momentum(fixed)[0]) < 0.9 * p0
    np.testing.assert_allclose(float(jaxmpm.diagnostics.momentum(free)[0]), p0, rtol=1e-12)


@pytest.mark.parametrize("side", ["lo", "hi"])
def test_separating_wall_lets_the_block_fall_away_a_slip_wall_holds_it(side):
    """The block against the wall with gravity pulling it away: a separating wall lets it fall
    freely (the centre of mass drops g t^2 / 2 to within the time step's first-order error,
    dt / t: measured 0.8%), a slip wall holds its nodes on the wall and with them the block
    (measured: 2.7% of the free fall; the ceiling film of the peers' mpm88 hung there against
    gravity)."""
    g = 9.81 if side == "lo" else -9.81
    scene, s0, sep = _run("separating", side, gravity=(0.0, g))
    _, _, slip = _run("slip", side, gravity=(0.0, g))
    free_fall = 0.5 * abs(g) * float(sep.t) ** 2

    def drop(s):
        return abs(float(np.average(s.x[:, 1], weights=s.mass) - np.average(s0.x[:, 1], weights=s0.mass)))

    assert drop(sep) == pytest.approx(free_fall, rel=0.02)
    np.testing.assert_allclose(
        float(jaxmpm.diagnostics.momentum(sep)[0]), float(jaxmpm.diagnostics.momentum(s0)[0]), rtol=1e-12
    )
    assert drop(slip) < 0.1 * free_fall


def _fragment_scene(speed: float, mirrored: bool, t_end: float, energy_update: str = "midpoint") -> Scene:
    """A 1 mm square al2024 fragment (hydrodynamic Mie-Grueneisen, 10 x 10 particles, cells of
    0.2 mm, viscosity (0.5, 2.0)) flying up at `speed` (m/s), 4 mm below the slip wall y = 8 mm;
    mirrored: the grid doubled upward, the wall gone from y = 8 mm, and the fragment's mirror image
    across it flying down at the same speed."""
    al = jaxmpm.materials.library_material("al2024", model="mie_gruneisen")
    phases = [Phase("fragment", "al2024", Box((5e-3, 3e-3), (6e-3, 4e-3)), velocity=(0.0, speed))]
    if mirrored:
        phases.append(Phase("image", "al2024", Box((5e-3, 12e-3), (6e-3, 13e-3)), velocity=(0.0, -speed)))
    return Scene(
        grid=Grid(cells=(40, 80 if mirrored else 40), h=0.2e-3),
        materials=(al,),
        phases=tuple(phases),
        boundary=Boundary(faces=tuple((f, "slip") for f in ("x_lo", "x_hi", "y_lo", "y_hi"))),
        artificial_viscosity=(0.5, 2.0),
        energy_update=energy_update,
        t_end=t_end,
        n_out=1,
    )


def fragment_into_wall(speed: float, energy_update: str = "midpoint") -> tuple[float, float]:
    """A 1 mm square al2024 fragment (hydrodynamic Mie-Grueneisen, 10 x 10 particles, cells of
    0.2 mm, viscosity (0.5, 2.0), float64) flying at `speed` (m/s) into a slip wall 4 mm away, run
    until it has rebounded, with the scene's `energy_update`. -> (largest total energy over the run / initial, largest specific
    internal energy / (speed^2 / 2): a rigid wall's shock heats to speed^2 / 2)."""
    import jax

    scene = dataclasses.replace(_fragment_scene(speed, False, 10e-3 / speed, energy_update), n_out=40)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    energy = np.asarray(jax.vmap(lambda s: jaxmpm.diagnostics.total_energy(scene, params, s))(hist))
    return float(energy.max() / energy[0]), float(hist.energy.max()) / (0.5 * speed**2)


def test_a_slip_wall_is_the_mirror_plane_of_a_head_on_impact():
    """A fragment hitting a slip wall at 3 km/s moves as one half of the head-on impact of the
    fragment and its mirror image in open grid, to round-off: the wall adds nothing of its own, so
    what the impact does (the contact's heating, the splash along it) is the impact's, not the wall's.
    Run to 2.5 us, 1.2 us into the impact (measured: positions equal to 3e-15 m, velocities to
    1.2e-8 m/s, internal energies to 1.4e-12 of the largest)."""
    finals = []
    for mirrored in (False, True):
        scene = _fragment_scene(3000.0, mirrored, 2.5e-6)
        params = jaxmpm.default_params(scene)
        finals.append(jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), progress=False)[0])
    wall, pair = finals
    n = wall.x.shape[0]
    assert float(np.asarray(wall.x)[:, 1].max()) > 8e-3 - 0.1e-3  # the fragment is on the wall
    np.testing.assert_allclose(np.asarray(pair.x[:n]), np.asarray(wall.x), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(pair.v[:n]), np.asarray(wall.v), rtol=0, atol=1e-5)
    e = np.asarray(wall.energy)
    np.testing.assert_allclose(np.asarray(pair.energy[:n]), e, rtol=0, atol=1e-9 * np.abs(e).max())


def test_a_slow_fragment_hitting_a_wall_does_not_gain_energy():
    """At 1 km/s the fragment keeps its energy (measured: the largest total 1.00009 of the start),
    but the wall's particles heat to 11x speed^2 / 2 (wall heating: the viscosity's work where the
    wall stops the particles next to it)."""
    gain, _ = fragment_into_wall(1000.0)
    assert gain < 1.001, gain


@pytest.mark.xfail(
    strict=True,
    reason="known limitation (docs/limitations.md): with the default energy update ('midpoint') a hypervelocity "
    "impact gains energy (on a slip wall, its mirror plane, as head-on): +0.7% at 3 km/s, +4.6% at 9 km/s; "
    "energy_update = 'compatible' keeps it exact",
)
def test_a_hypervelocity_fragment_hitting_a_wall_does_not_gain_energy():
    """At 3 km/s (measured: the total rises to 1.007 of the start)."""
    gain, _ = fragment_into_wall(3000.0)
    assert gain < 1.001, gain


@pytest.mark.parametrize("speed", [1000.0, 3000.0, 9000.0])
def test_the_compatible_energy_update_keeps_a_hypervelocity_impact_exact(speed):
    """With energy_update = 'compatible' the hydrocode models' internal energy is the work the grid's
    forces did (`force_work_velocity`), so the total is exact whatever the impact (measured: the
    largest total over the run 1 + 2.2e-16 of the start at 1 and 3 km/s, 1 + 0 at 9). With the
    default 'midpoint' it rises to 1.00009, 1.007 and 1.046 of the start: the impact's pressure rises
    within a step, and the energy takes its midpoint value where the forces worked with its start
    value. What the exact total does not change: the particles at the contact heat to 4-10x
    speed^2 / 2 (a rigid wall's shock heats to speed^2 / 2; docs/limitations.md)."""
    gain, _ = fragment_into_wall(speed, "compatible")
    assert gain < 1 + 1e-12, gain


def test_the_energy_update_goes_through_a_scene_file():
    """energy_update = 'compatible' is written to a scene file and read back; the default is not
    written."""
    from jaxmpm.io.scenefile import scene_from_toml, scene_to_toml

    scene = _fragment_scene(1000.0, False, 1e-6)
    assert "energy_update" not in scene_to_toml(scene)
    on = dataclasses.replace(scene, energy_update="compatible")
    assert 'energy_update = "compatible"' in scene_to_toml(on)
    assert scene_from_toml(scene_to_toml(on)) == on
