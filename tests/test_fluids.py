"""Free-surface water with the default scheme (DDMP, 'musl'): a collapsing water column hitting a
wall, water at rest in a tank, the peers' mpm88 fluid.

The dam break: the classic water column of Martin & Moyce (1952), width a = 2.25 in = 0.057 m and
height 2a, at rest, collapsing under gravity in a closed 5a x 5a box with slip walls; Tait water
with its sound speed lowered to 25 m/s (12x the fastest flow) so the run is short. Reference: the
surge front Z = x / a against T = t sqrt(2 g / a) of their Fig. 3 for n^2 = 2, a = 2.25 in
(J. C. Martin and W. J. Moyce, Phil. Trans. R. Soc. Lond. A 244 (1952) 312-324, Part IV), as
digitised in PySPH's examples (pypr/pysph, pysph/examples/db_exp_data.py).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm import Box, Grid, Phase, Scene
from jaxmpm.materials.library import library_material
from jaxmpm.model.geometry import Difference
from jaxmpm.model.state import phase_slices

G = 9.81
A = 0.057  # column width, m (2.25 in)
C_WATER = 25.0  # lowered sound speed, m/s
# Martin & Moyce (1952) Fig. 3, n^2 = 2, a = 2.25 in: (T, Z)
MARTIN_MOYCE = np.array(
    [
        [0.832, 1.217],
        [1.219, 1.474],
        [1.997, 2.292],
        [2.547, 2.995],
        [3.345, 4.134],
        [4.034, 4.944],
        [4.418, 5.881],
        [5.091, 6.980],
        [5.685, 7.945],
        [6.306, 8.966],
    ]
)


def water(c=C_WATER, p0=0.0):
    """Tait water (rho0 = 1000 kg/m^3, n = 7.15, p0 Pa) of sound speed c at rest."""
    return library_material("water", "tait", tait_B=1000.0 * c**2 / 7.15, p0=p0)


def dam_break(cells_per_a: int, T_end: float, cfl: float = 0.3, **changes) -> Scene:
    """The column a x 2a in a closed 5a x 5a box with slip walls, 2 x 2 particles per cell."""
    walls = jaxmpm.Boundary(faces=tuple((f, "slip") for f in ("x_lo", "x_hi", "y_lo", "y_hi")))
    scene = Scene(
        grid=Grid(cells=(5 * cells_per_a, 5 * cells_per_a), h=A / cells_per_a),
        materials=(water(),),
        phases=(Phase("water", "water", Box((0.0, 0.0), (A, 2 * A)), ppc=2),),
        boundary=walls,
        gravity=(0.0, -G),
        t_end=T_end / math.sqrt(2 * G / A),
        cfl=cfl,
        name="dam_break",
    )
    return dataclasses.replace(scene, **changes)


def run_dam_break(scene, n_out):
    """-> (T (n_out + 1,), energy change / (m g a), front Z = max x / a, max speed / free-fall speed
    from the column's top sqrt(2 g 2a))."""
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, n_out=n_out, progress=False)
    mga = float(jnp.sum(s0.mass)) * G * A
    energy = jax.vmap(lambda s: jaxmpm.diagnostics.total_energy(scene, params, s))(hist)
    T = np.asarray(hist.t) * math.sqrt(2 * G / A)
    dE = (np.asarray(energy) - float(energy[0])) / mga
    Z = np.asarray(jnp.max(hist.x[..., 0], axis=-1)) / A
    vmax = np.asarray(jnp.max(jnp.linalg.norm(hist.v, axis=-1), axis=-1)) / math.sqrt(2 * G * 2 * A)
    return T, dE, Z, vmax


def front_speed(T, Z, lo=3.0, hi=4.5):
    """dZ/dT between the times the front passes Z = lo and Z = hi (linear interpolation)."""

    def crossing(z):
        k = int(np.argmax(Z >= z))
        return T[k - 1] + (z - Z[k - 1]) * (T[k] - T[k - 1]) / (Z[k] - Z[k - 1])

    return (hi - lo) / (crossing(hi) - crossing(lo))


def tank_at_rest(cells_per_H: int = 20, H: float = 0.1) -> tuple[Scene, object, object]:
    """Water of depth H (m) at rest in a tank 2H wide with slip walls, under gravity, started from
    the hydrostatic state: p = rho0 g (H - y) and the Tait density of that pressure.
    -> (scene, params, initial state)."""
    walls = jaxmpm.Boundary(faces=tuple((f, "slip") for f in ("x_lo", "x_hi", "y_lo", "y_hi")))
    h = H / cells_per_H
    scene = Scene(
        grid=Grid(cells=(2 * cells_per_H, cells_per_H + 4), h=h),
        materials=(water(),),
        phases=(Phase("water", "water", Box((0.0, 0.0), (2 * H, H)), ppc=2),),
        boundary=walls,
        gravity=(0.0, -G),
        cfl=0.3,
        name="tank",
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    c = params.phases["water"]
    p = c["rho0"] * G * (H - s0.x[:, 1])
    rho = c["rho0"] * (1 + p / c["tait_B"]) ** (1 / c["tait_n"])  # Tait with p0 = 0
    d = scene.dim
    s0 = dataclasses.replace(
        s0,
        volume=s0.mass / rho,
        pressure=p,
        stress=-p[:, None, None] * jnp.eye(d, dtype=p.dtype),
        F=jnp.broadcast_to(jnp.eye(d, dtype=p.dtype) * (c["rho0"] / rho)[:, None, None] ** (1 / d), s0.F.shape),
    )
    return scene, params, s0


def tank_errors(scene, s0, s, H=0.1):
    """-> (max speed / sqrt(g H), largest error of the band-averaged interior pressure against
    rho0 g (H - y) / (rho0 g H), the particle scatter (std) of p - rho0 g (H - y) / (rho0 g H)).
    Interior: two cells from the walls and the free surface; bands one cell high."""
    h = scene.grid.h
    rho_gH = 1000.0 * G * H
    x, p = np.asarray(s.x), np.asarray(s.pressure)
    y0 = np.asarray(s0.x[:, 1])
    inner = (x[:, 0] > 2 * h) & (x[:, 0] < 2 * H - 2 * h) & (y0 > 2 * h) & (y0 < H - 2 * h)
    dev = (p - 1000.0 * G * (H - y0))[inner] / rho_gH
    bands = np.floor(y0[inner] / h).astype(int)
    band_err = max(abs(dev[bands == b].mean()) for b in np.unique(bands))
    speed = float(jnp.max(jnp.linalg.norm(s.v, axis=-1))) / math.sqrt(G * H)
    return speed, band_err, float(dev.std())


def _check_dam_break(T, dE, Z, vmax):
    assert np.all(np.isfinite(dE))
    # the collapse, the impact on the far wall (T ~ 3.8) and the run-up only lose energy
    assert dE.max() < 1e-3, f"energy rose by {dE.max():.2e} m g a (at T = {T[np.argmax(dE)]:.2f})"
    # no runaway particle: the thin jet the impact sends up the wall peaks at 2.2x (10 cells) and 2.6x
    # (20 cells) the free-fall speed from the column's top around T = 4, then falls below 2x by T = 4.5;
    # without the fluids' artificial viscosity particles reached 44x (20 cells, float32)
    assert vmax.max() < 3.0, f"a particle at {vmax.max():.2f} x the free-fall speed from the column's top"
    assert vmax[T >= 5.0].max() < 2.0
    # the surge front: its speed before the wall (Z from 3.5 to 4.75) against the experiment's once past
    # the gate's opening (3 <= T <= 5.1, dZ/dT = 1.67: the experiment's front starts late and accelerates
    # while the gate is drawn, so its positions trail a column released at once by ~10% early on).
    # Within 10%: the experiment's smaller column (a = 1.125 in) gives 1.27 over the same range, so the
    # measurement itself spreads by 30% (measured here: -6.0% at 10 cells, -6.8% at 20 cells)
    late = (MARTIN_MOYCE[:, 0] >= 3.0) & (MARTIN_MOYCE[:, 0] <= 5.1)
    measured = np.polyfit(MARTIN_MOYCE[late, 0], MARTIN_MOYCE[late, 1], 1)[0]
    speed = front_speed(T, Z, 3.5, 4.75)
    assert abs(speed / measured - 1) < 0.1, (speed, measured)
    assert Z[-1] > 4.9  # the surge reached the far wall


@pytest.mark.slow
def test_dam_break_hits_the_wall_without_gaining_energy():
    """10 cells per a, CFL 0.3, through the impact to T = 5: the energy never rises (with no
    artificial viscosity, the default before fluids had one, it rose 0.5% of m g a by T = 5, 1.7% by
    T = 6 and without bound after), and the surge front moves at the measured speed."""
    _check_dam_break(*run_dam_break(dam_break(10, 5.0), 20))


@pytest.mark.slow
def test_dam_break_at_20_cells_through_the_run_up():
    """20 cells per a, CFL 0.3, through the impact and the run-up to T = 8 (measured: the energy
    falls monotonically, -2.0e-3 m g a by T = 8; without the fluids' artificial viscosity +93% of
    m g a by T = 7, float32)."""
    _check_dam_break(*run_dam_break(dam_break(20, 8.0), 32))


def test_density_diffusion_is_a_scene_option():
    """effects.density_diffusion (delta, default 0.1): 0 traces no diffusion; a scene file keeps it;
    delta scales the relaxation rate delta c / h (E: `density_diffusion_rate`)."""
    from jaxmpm.io.scenefile import scene_from_toml, scene_to_toml
    from jaxmpm.stages.density_diffusion import density_diffusion_rate, diffused_particles
    from jaxmpm.stages.layout import Layout
    from jaxmpm.numerics.shapes import stencil

    scene = dam_break(4, 1.0)
    assert scene.density_diffusion == 0.1
    assert diffused_particles(Layout.of(dataclasses.replace(scene, density_diffusion=0.0))) is None
    assert scene_from_toml(scene_to_toml(dataclasses.replace(scene, density_diffusion=0.05))).density_diffusion == 0.05
    assert "density_diffusion" not in scene_to_toml(scene)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    s0 = dataclasses.replace(s0, volume=s0.volume * (1 + 0.01 * jnp.sin(37.0 * s0.x[:, 0] / A)))
    rates = []
    for delta in (0.1, 0.05):
        sc = dataclasses.replace(scene, density_diffusion=delta)
        lay = Layout.of(sc)
        rates.append(density_diffusion_rate(lay, params, stencil(sc, s0.x), s0, diffused_particles(lay)))
    assert float(jnp.max(jnp.abs(rates[0]))) > 0
    np.testing.assert_allclose(np.asarray(rates[1]), 0.5 * np.asarray(rates[0]), rtol=1e-12, atol=0)


def pressure_scatter(x, p, h, L, ppc=4):
    """The particle pressure noise of a flow: (std, largest |.|) of each particle's pressure less its
    cell's mean, over the particles of cells that, with their 8 neighbours, hold at least ppc - 1
    particles (away from the free surface) and lie 2 cells or more from the walls of the L x L box.
    x (N, 2) m, p (N,) Pa -> Pa."""
    ci = np.floor(np.asarray(x) / h).astype(int)
    n = int(round(L / h))
    count, psum = np.zeros((n, n)), np.zeros((n, n))
    np.add.at(count, (ci[:, 0], ci[:, 1]), 1)
    np.add.at(psum, (ci[:, 0], ci[:, 1]), np.asarray(p))
    mean = psum / np.maximum(count, 1)
    full = count >= ppc - 1
    ok = np.zeros_like(full)
    ok[1:-1, 1:-1] = np.all(
        [full[1 + i : n - 1 + i, 1 + j : n - 1 + j] for i in (-1, 0, 1) for j in (-1, 0, 1)], axis=0
    )
    inner = ok[ci[:, 0], ci[:, 1]] & np.all((ci >= 2) & (ci < n - 2), -1)
    dev = (np.asarray(p) - mean[ci[:, 0], ci[:, 1]])[inner]
    return float(dev.std()), float(np.abs(dev).max())


def _collapse_pressure_noise(cells_per_a, T_end=3.0):
    """-> [(std, max) of `pressure_scatter` / (rho0 g 2a) at T = 1, 2, ..., T_end] of the dam break."""
    scene = dam_break(cells_per_a, T_end)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, n_out=int(T_end), progress=False)
    rho_g_2a = 1000.0 * G * 2 * A
    return [
        tuple(v / rho_g_2a for v in pressure_scatter(hist.x[k], hist.pressure[k], scene.grid.h, 5 * A))
        for k in range(1, int(T_end) + 1)
    ]


@pytest.mark.parametrize("cells", [pytest.param(20, marks=pytest.mark.slow), 10])
def test_collapsing_column_pressure_is_not_noisy(cells):
    """The collapsing column before it reaches the far wall (T = 1, 2, 3): the particle pressures'
    scatter within a cell, away from the walls and the free surface, stays below 0.3 rho g 2a (std)
    and 1.5 rho g 2a (largest), rho g 2a = 1118 Pa the column's hydrostatic pressure at rest.
    Measured (float32), largest std / largest |.| over T = 1-3: 0.15 / 0.51 (10 cells), 0.12 / 0.92
    (20 cells); without the fluids' density diffusion 1.04 / 4.4 (10 cells) and 0.81 / 5.0
    (20 cells): DDMP's blend gives the particles of one cell different volume rates, and the grid
    does not see volume errors that differ within a cell."""
    for T, (std, largest) in enumerate(_collapse_pressure_noise(cells), start=1):
        assert std < 0.3 and largest < 1.5, (T, std, largest)


@pytest.mark.slow
def test_dam_break_at_40_cells_through_the_run_up():
    """40 cells per a, CFL 0.3, to T = 8 (the issue measured +33% of m g a by T = 5 and particles at
    13,456 m/s by T = 5.5 before the fluids' artificial viscosity). Measured: the energy never rises,
    -8.8% of m g a by T = 8; at most 2.3x the free-fall speed (1.6x from T = 5); the front 6.1% slower
    than the experiment's. 12 minutes on a loaded 2-core CPU."""
    _check_dam_break(*run_dam_break(dam_break(40, 8.0), 32))


@pytest.mark.slow
def test_dam_break_at_cfl_0_1_through_the_run_up():
    """20 cells per a, CFL 0.1, to T = 8 (the issue measured +1.8% of m g a by T = 8 before the fluids'
    artificial viscosity). Measured: the energy never rises, -8.5% of m g a by T = 8; at most 2.4x the
    free-fall speed (1.5x from T = 5); the front 7.0% slower than the experiment's."""
    _check_dam_break(*run_dam_break(dam_break(20, 8.0, cfl=0.1), 32))


def _tank_run(steps):
    scene, params, s0 = tank_at_rest(20)
    step = jax.jit(jaxmpm.make_step(scene))
    s = jax.lax.fori_loop(0, steps, lambda i, s: step(params, s), s0)
    return tank_errors(scene, s0, s)


@pytest.mark.parametrize("steps", [pytest.param(10_000, marks=pytest.mark.slow), 2_000])
def test_water_at_rest_in_a_tank_stays_hydrostatic(steps):
    """Water 0.1 m deep, 20 cells, from the hydrostatic state: largest speed below 1e-3 sqrt(g H),
    the interior pressure within 1% of rho g (H - y) band by band and its particle scatter below
    10% of rho g H."""
    speed, band, scatter = _tank_run(steps)
    assert speed < 1e-3
    assert band < 1e-2
    assert scatter < 0.1


def water_and_air(
    cells_per_a: int,
    gravity: float = G,
    shape: str = "ddmp",
    T_end: float = 8.0,
    ambient_pressure: float | None = 101325.0,
) -> Scene:
    """The dam break's column with air filling the rest of the box in a field of its own: Tait water
    (c = 25 m/s) and library air (ideal gas), both at 1 atm, the grid seeing their gauge stresses
    (Scene.ambient_pressure = 1 atm; None: their absolute stresses)."""
    column = Box((0.0, 0.0), (A, 2 * A))
    box = Box((0.0, 0.0), (5 * A, 5 * A))
    return dataclasses.replace(
        dam_break(cells_per_a, T_end, gravity=(0.0, -gravity), shape=shape),
        materials=(water(p0=101325.0), library_material("air")),
        phases=(
            Phase("water", "water", column, ppc=2, field=0),
            Phase("air", "air", Difference(box, (column,)), ppc=2, field=1),
        ),
        ambient_pressure=ambient_pressure,
        name="dam_break_air",
    )


ABSOLUTE_STRESS = pytest.mark.xfail(
    strict=True,
    reason="known limitation (issue 49): with the absolute stresses (no ambient pressure) the air's "
    "own pressure, 1 atm, pushes its nodes as its particles move within their cells (and, with DDMP, "
    "each field's pressure pushes the nodes beside the interface that only it occupies)",
)


@pytest.mark.parametrize(
    "shape, ambient",
    [
        ("ddmp", 101325.0),
        ("linear", 101325.0),
        pytest.param("ddmp", None, marks=ABSOLUTE_STRESS),
        pytest.param("linear", None, marks=ABSOLUTE_STRESS),
    ],
)
def test_water_and_air_at_one_pressure_stay_at_rest(shape, ambient):
    """The fast sibling of the two-field dam break: water and air at the same uniform pressure
    (1 atm), without gravity, 200 steps of 5e-6 s (1 ms): nothing moves. Measured with the gauge
    stresses: 1.0e-12 m/s (DDMP), 1.2e-12 m/s (linear). With the absolute stresses: DDMP 2.2 m/s
    after one step, the air beside the interface pushed toward the water along the whole
    interface (4e5 m/s^2, in proportion to the pressure, not its gradient), 320 m/s after 300
    steps; linear shapes 2e-14 m/s after 20 steps but 9.8e-4 m/s after 200 and 190 m/s after 300."""
    scene = water_and_air(10, gravity=0.0, shape=shape, ambient_pressure=ambient)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    step = jaxmpm.make_step(scene)
    s = jax.jit(lambda s: jax.lax.fori_loop(0, 200, lambda i, s: step(params, s, jnp.inf, 5e-6), s))(s0)
    assert float(jnp.max(jnp.abs(s0.pressure - 101325.0))) < 1e-6
    speed = float(jnp.max(jnp.linalg.norm(s.v, axis=-1)))
    assert speed < 1e-6, speed


def two_field_dam_break(cells_per_a: int, T_end: float, n_out: int, ambient_pressure: float | None = 101325.0):
    """The dam break with air in its own field (`water_and_air`), run to T_end. -> (T (n_out + 1,),
    energy change / (m g a) with m the water's mass, the energy above its lowest value so far /
    (m g a), the water's front Z = max x / a, the largest speed of any particle / the free-fall
    speed from the column's top sqrt(2 g 2a)). ambient_pressure: as `water_and_air`'s. The energy holds the air's internal energy and the
    surroundings' p_a V (`jaxmpm.diagnostics.total_energy`)."""
    scene = water_and_air(cells_per_a, T_end=T_end, ambient_pressure=ambient_pressure)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, n_out=n_out, progress=False)
    water_particles = phase_slices(scene)[0]
    mga = float(jnp.sum(s0.mass[water_particles])) * G * A
    energy = np.asarray(jax.vmap(lambda s: jaxmpm.diagnostics.total_energy(scene, params, s))(hist))
    T = np.asarray(hist.t) * math.sqrt(2 * G / A)
    dE = (energy - energy[0]) / mga
    above = dE - np.minimum.accumulate(dE)
    Z = np.asarray(jnp.max(hist.x[:, water_particles, 0], axis=-1)) / A
    vmax = np.asarray(jnp.max(jnp.linalg.norm(hist.v, axis=-1), axis=-1)) / math.sqrt(2 * G * 2 * A)
    return T, dE, above, Z, vmax


def air_squeezed_against_a_wall(cells: int = 20, n_out: int = 20):
    """A water block (0.1 m x 0.1 m on the floor of a closed 0.2 m x 0.2 m box of slip walls, Tait
    water of `water`) flying at V = 2 m/s toward the right wall, its gap to the wall closing from 5 cm
    to two cells; air at 1 atm in a field of its own filling the rest (gauge stresses), no gravity,
    CFL 0.3, `cells` cells a side, 2 x 2 particles per cell. The air in the gap has one way out, up
    past the block's top corner, and continuity sets its speed: an incompressible gas crosses the
    gap's top, y = Hb, at the rate the block sweeps, V Hb (m^2/s), at the mean speed V Hb / g.
    -> (gap g (n_out + 1,) m, air volume in the gap below Hb (m^2), air flux up across y = Hb within
    the gap (m^2/s), V, Hb), the flux from the air particles within half a cell of Hb."""
    side, V, Hb, x0, W = 0.2, 2.0, 0.1, 0.05, 0.1
    h = side / cells
    block = Box((x0, 0.0), (x0 + W, Hb))
    scene = Scene(
        grid=Grid(cells=(cells, cells), h=h),
        materials=(water(p0=101325.0), library_material("air")),
        phases=(
            Phase("water", "water", block, ppc=2, field=0, velocity=(V, 0.0)),
            Phase("air", "air", Difference(Box((0.0, 0.0), (side, side)), (block,)), ppc=2, field=1),
        ),
        boundary=jaxmpm.Boundary(faces=tuple((f, "slip") for f in ("x_lo", "x_hi", "y_lo", "y_hi"))),
        gravity=(0.0, 0.0),
        t_end=(side - x0 - W - 2 * h) / V,
        cfl=0.3,
        ambient_pressure=101325.0,
        name="air_squeeze",
    )
    params = jaxmpm.default_params(scene)
    _, hist = jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), n_out=n_out, progress=False)
    w, a = phase_slices(scene)
    x, v, vol = np.asarray(hist.x), np.asarray(hist.v), np.asarray(hist.volume)
    gap = side - (x[:, w, 0].max(axis=1) + h / 4)  # the block's face: its last particles + half their spacing
    xa, va, Va = x[:, a], v[:, a], vol[:, a]
    in_gap = xa[..., 0] > side - gap[:, None]
    volume = np.sum(Va * (in_gap & (xa[..., 1] < Hb)), axis=1)
    band = in_gap & (np.abs(xa[..., 1] - Hb) < h / 2)
    flux = np.sum(Va * va[..., 1] * band, axis=1) / h
    return gap, volume, flux, V, Hb


def test_air_squeezed_against_a_wall_escapes_at_the_speed_continuity_sets():
    """The fast air of the two-field dam break is air escaping between the water and the wall: here
    the same squeeze in a geometry with a kinematic answer. The air stays out of the water and is not
    compressed (its volume in the gap is g Hb) and leaves across the gap's top at the rate V Hb, so its
    mean speed there is V Hb / g: 4 m/s (2x the block's) at a gap of 5 cells, 10 m/s (5x) at 2 cells,
    without a bound as the gap closes. A speed bound tied to the water's speed does not hold for the
    air in such a gap. Measured (20 cells): the air's volume in the gap within 2.2% of g Hb from 5 cells
    to 2; the flux, averaged over the 20 outputs, 0.98 of V Hb (single outputs 0.52-1.40: the band
    holds few particles); the fastest air particle 8-16 m/s (4-8x V)."""
    gap, volume, flux, V, Hb = air_squeezed_against_a_wall()
    assert gap[-1] < 0.025 and gap[0] == pytest.approx(0.05, rel=0.01)
    np.testing.assert_allclose(volume, gap * Hb, rtol=0.03)
    assert np.mean(flux[1:]) == pytest.approx(V * Hb, rel=0.1)


def test_two_field_dam_break_starts_without_gaining_energy():
    """Water and air at 1 bar in the closed box, 5 cells per a, CFL 0.3 (dt = 1e-5 s, set by the
    air's sound speed), to T = 0.04 (216 steps): the energy never more than 0.5% of m g a above its
    lowest value so far (the issue's bound) and no particle faster than twice the free-fall speed
    from the column's top. Measured: the energy falls monotonically (-1.9e-6 m g a), the fastest
    particle at 0.048x. With the absolute stresses (ambient_pressure None) particles reach 27x by
    T = 0.01 and 143x by T = 0.04, while the energy falls by 5.2 m g a."""
    T, dE, above, Z, vmax = two_field_dam_break(5, 0.04, 4)
    assert np.all(np.isfinite(dE)) and T[-1] > 0.0399
    assert above.max() < 5e-3, above
    assert vmax.max() < 2.0, vmax


@pytest.mark.slow
def test_two_field_dam_break_collapses_without_gaining_energy():
    """The same at 10 cells per a (dt = 5e-6 s) to T = 2 (t = 0.108 s, 21,541 steps; about 10
    minutes on a loaded 2-core CPU): the issue's energy bound and speed bound, and the front moving.
    Measured: the energy falls monotonically, -2.6e-3 m g a by T = 2; the fastest water particle
    at 0.96x, the fastest air particle at 1.5x the free-fall speed from the column's top; the front
    at Z = 2.57."""
    T, dE, above, Z, vmax = two_field_dam_break(10, 2.0, 10)
    assert np.all(np.isfinite(dE))
    assert above.max() < 5e-3, above
    assert vmax.max() < 2.0, vmax
    assert Z[-1] > 2.0, Z


def mpm88_run(shape):
    """The peers' mpm88 (float32, 128^2, the peers' separating walls) with `shape` and the default
    'musl' update at the peers' step 2e-4 s for benchmarks/throughput.py's whole run (2000 steps, t = 0.4 s). -> (finite,
    max speed m/s, relative energy change), the benchmark's stability measures."""
    scene = dataclasses.replace(jaxmpm.load_scene("mpm88"), shape=shape, transfer="musl")
    params = jaxmpm.default_params(scene, dtype=jnp.float32)
    s0 = jaxmpm.init_state(scene, params)
    step = jaxmpm.make_step(scene)
    dt = jnp.float32(2e-4)
    s = jax.jit(lambda s: jax.lax.fori_loop(0, 2000, lambda i, s: step(params, s, jnp.inf, dt), s))(s0)

    def energy(s):
        return float(jnp.sum(s.mass * (0.5 * jnp.sum(s.v**2, -1) - s.x @ params.gravity + s.energy)))

    finite = all(bool(np.isfinite(np.asarray(a)).all()) for a in jax.tree.leaves(s))
    inside = bool(((np.asarray(s.x) >= 0) & (np.asarray(s.x) <= 1)).all())
    return finite and inside, float(jnp.max(jnp.linalg.norm(s.v, axis=-1))), (energy(s) - energy(s0)) / abs(energy(s0))


@pytest.mark.slow
@pytest.mark.xfail(
    strict=False,
    reason="known limitation (issue 49): with the peers' separating walls the 'linear' run gains energy "
    "(+4.5% by t = 0.4 s at XLA's optimisation level 0, +4.8% at the default level); with slip walls it "
    "passed at the default level and reached 10.3 m/s at level 0",
)
def test_mpm88_with_linear_shapes_and_musl_is_stable_at_the_peers_step():
    """Before the fluids' artificial viscosity this run went non-finite (benchmarks/results/throughput.csv);
    with it, but with the pressure from det F, particles reached 18.8 m/s at the ceiling. Measured
    now (separating walls, float32): finite, 6.6 m/s, energy +4.5% (level 0) and +4.8% (default)."""
    finite, vmax, de = mpm88_run("linear")
    assert finite and vmax < 10.0 and de < 0.01, (finite, vmax, de)


@pytest.mark.slow
def test_mpm88_with_the_default_scheme_is_stable_at_the_peers_step():
    """With the pressure from det F, splashed particles at the ceiling and its corner reached
    det F = 0.2-0.4 while their volume grew 2.6-3.5x: pushed apart by a compressive pressure, the run
    went non-finite at t ~ 0.39 s (and at half and a quarter of the step). With slip walls (which
    hold the normal velocity both ways) a film of single particles hung on the ceiling against
    gravity; a jet rising into it compressed the film particle on the wall's first node to
    J = 0.38, which could expand only along the wall and shot its neighbour along the ceiling at
    14 m/s, and at the peers' fixed step two such particles meeting at 11 m/s went unstable
    (t = 0.355 s at XLA's optimisation level 0, 1109 m/s; stable at the default level by chance).
    The peers' walls (`mpm88`'s 'separating' faces) let the film fall. Measured (float32): finite,
    8.0 m/s, energy -12.0% (level 0); 7.0 m/s, -11.9% (default level)."""
    finite, vmax, de = mpm88_run("ddmp")
    assert finite and vmax < 10.0 and de < 0.01, (finite, vmax, de)


def test_linear_fluid_pressure_follows_the_particle_volume_under_rotation():
    """The fast sibling of the mpm88 runs: a linear fluid turned by a velocity gradient with a large
    rotational part keeps the pressure of its volume ratio, here none (the pressure from the forward
    update's det F drifted by 2.5e-3 K a step at dt w = 0.05, to 0.13 K after 50 steps)."""
    from jaxmpm.materials import MatPoint, model_of

    c = {"rho0": 1.0, "K": 400.0}
    dt, w, n = 1e-3, 50.0, 50
    L = jnp.array([[[0.0, w], [-w, 0.0]]])  # a rigid rotation: tr L = 0, the volume stays
    D = 0.5 * (L + jnp.swapaxes(L, 1, 2))
    one = jnp.ones(1)
    mp = MatPoint(jnp.eye(2)[None], jnp.zeros((1, 2, 2)), 0 * one, 0 * one, 0 * one, 0 * one, one, one)
    update = model_of("linear_fluid").update
    for _ in range(n):
        mp = update(c, mp, L, D, dt, dt * one, None, None)._replace(rho=one, rho_new=one)
    assert abs(float(mp.pressure[0])) < 1e-6 * c["K"], float(mp.pressure[0])
    # and a compression to half the volume gives p = K (1 - J) with J = rho0 / rho
    mp = update(c, mp._replace(rho_new=2 * one), 0 * L, 0 * D, dt, dt * one, None, None)
    assert float(mp.pressure[0]) == pytest.approx(0.5 * c["K"], rel=1e-12)
