"""The debris cloud in a gas-filled chamber (`debris_cloud(chamber_pressure=...)`): the chamber's air
in its own velocity field, coupled to the solids by the exchange drag (E3) and the common pressure
(E6, E13). Checked: the scene's layout and its bad input, the air at rest before the impact, mass,
momentum and energy (with the drag's heat), the front's slowing against a drag estimate, the bow
shock against the normal-shock (Rankine-Hugoniot) jump, and d(point 1 velocity)/d log C_d against
central differences. float64 (conftest)."""

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm import diagnostics, features
from jaxmpm.materials.library import library_constants
from jaxmpm.scenes.impact import IMPACT_SPEED, chamber_air
from jaxmpm.model.geometry import Box, Difference
from jaxmpm.model.state import phase_slices
from jaxmpm.step import cfl_time_step

LOW, HIGH = 1e4, 1.05e6  # Pa: the seed's chambers, 0.1 and 10.5 bar


def cloud(**kw):
    return jaxmpm.load_scene("debris_cloud", **{"resolution": 0.75, **kw})


def run(scene, t_end=None, n_out=1, params=None):
    params = jaxmpm.default_params(scene) if params is None else params
    s0 = jaxmpm.init_state(scene, params)
    final, hist = jaxmpm.simulate(scene, params, s0, t_end=t_end, n_out=n_out, progress=False)
    return params, s0, final, hist


def at(hist, k):
    return jax.tree.map(lambda a: a[k], hist)


@pytest.mark.parametrize("bad", [-1e5, 0.0, float("inf"), float("nan"), "1 bar", True])
def test_bad_chamber_pressure_is_refused_naming_the_field_and_range(bad):
    with pytest.raises(ValueError) as e:
        cloud(chamber_pressure=bad)
    assert f"debris_cloud: chamber_pressure = {bad!r} is invalid: allowed a finite number > 0 Pa" in str(e.value)
    assert "not given: vacuum" in str(e.value)


def test_chamber_layout_air_in_its_own_field_and_vacuum_unchanged():
    vacuum = cloud()
    assert vacuum == cloud(chamber_pressure=None)
    assert [p.name for p in vacuum.phases] == ["projectile", "plate"]
    c = library_constants("air")
    for fields, expect in ((1, [0, 0, 1]), (2, [0, 1, 2])):
        s = cloud(fields=fields, chamber_pressure=HIGH)
        assert [p.name for p in s.phases] == ["projectile", "plate", "air"]
        assert [p.field for p in s.phases] == expect
        assert s.grid == cloud(fields=fields).grid and s.drag == 1.0
        assert s.pressure_fields == tuple(range(fields + 1))  # the air shares the common pressure
        air = s.material(s.phases[2])
        assert dict(air.constants)["p0"] == HIGH
        assert dict(air.constants)["rho0"] == pytest.approx(HIGH / (c["R"] * c["T_room"]), rel=1e-12)  # 12.69 kg/m^3
        assert jaxmpm.io.scenefile.scene_from_toml(jaxmpm.scene_to_toml(s)) == s
    # the air fills the grid around the sphere and the plate but for the sphere's shadow (r < R, from
    # the plate to the sphere's equator): the phases' volumes add up to the grid's less the shadow's
    s = cloud(chamber_pressure=LOW)
    params = jaxmpm.default_params(s)
    s0 = jaxmpm.init_state(s, params)
    r_hi, z_lo, z_hi = s.grid.hi[0], s.grid.origin[1], s.grid.hi[1]
    R, gap = s.phases[0].geometry.radius, s.grid.h
    shadow = 0.5 * R**2 * (R + gap) - (2 / 3) * R**3 / 2  # per radian: the cylinder less the half sphere
    expect = 0.5 * r_hi**2 * (z_hi - z_lo) - shadow
    assert float(jnp.sum(s0.volume)) == pytest.approx(expect, rel=2e-3)
    air = np.asarray(s0.x[phase_slices(s)[2]])
    assert not np.any((air[:, 0] < R) & (air[:, 1] > 0) & (air[:, 1] < gap))
    assert chamber_air(LOW).key == "air"


def test_chamber_pressure_from_the_command_line(tmp_path, capsys):
    from jaxmpm import cli

    opts = cli._pairs(["resolution=0.75", "chamber_pressure=1.05e6"], "--opt")
    assert cli._load("debris_cloud", {}, opts) == cloud(chamber_pressure=HIGH)
    argv = ["run", "--out", str(tmp_path), "--no-progress", "debris_cloud", "--opt", "chamber_pressure=-1e5"]
    assert cli.main(argv) == 2
    assert "chamber_pressure = -100000.0 is invalid: allowed a finite number > 0 Pa" in capsys.readouterr().err


def test_the_air_at_rest_stays_at_rest_until_the_first_contact():
    """The 10.5 bar chamber with the sphere (nearly) at rest, over the time the sphere at 6.71 km/s
    takes to reach the plate (its gap, one cell): the sampling and the pressure estimate move the air
    by less than 1 m/s (the solids carry the air's pressure at their faces: the common pressure).
    The sphere's shadow (r < R between the plate and the sphere's equator) holds no air, so the air
    at its edge expands into it as a gas into an empty space (here to 18 m/s, far below the escape
    speed 2 c / (gamma - 1) = 1.7 km/s); the 1 m/s holds beyond two cells of it."""
    scene = cloud(chamber_pressure=HIGH, speed=1e-3, plate_radius=6e-3)
    h = gap = scene.grid.h
    R = scene.phases[0].geometry.radius
    t_contact = gap / IMPACT_SPEED
    _, s0, final, _ = run(scene, t_end=t_contact)
    air = phase_slices(scene)[2]
    assert float(final.t) == pytest.approx(t_contact)
    x, speed = np.asarray(s0.x[air]), np.asarray(jnp.linalg.norm(final.v[air], axis=-1))
    by_shadow = (x[:, 0] < R + 2 * h) & (x[:, 1] > -2 * h) & (x[:, 1] < R + gap + 2 * h)
    assert by_shadow.sum() < 0.05 * len(x)
    print("air speed beyond the shadow", speed[~by_shadow].max(), "by it", speed[by_shadow].max())
    assert speed[~by_shadow].max() < 1.0
    assert speed[by_shadow].max() < 100.0


@functools.lru_cache(maxsize=1)
def short_three_field_run():
    """10.5 bar, three fields (projectile | plate | air), the drag's heat booked, a plate of 6 mm
    radius (a smaller grid), 0.3 us: the sphere goes into the plate; no wave has reached a wall."""
    scene = cloud(fields=2, chamber_pressure=HIGH, drag_heating=True, plate_radius=6e-3)
    return (scene, *run(scene, t_end=0.3e-6, n_out=2))


def test_chamber_conserves_mass_momentum_and_energy_with_the_drag_heat():
    scene, params, s0, final, hist = short_three_field_run()
    assert all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(final))
    np.testing.assert_array_equal(np.asarray(final.mass), np.asarray(s0.mass))
    p0, p1 = (np.asarray(diagnostics.momentum(s)) for s in (s0, final))
    assert abs(p1[1] - p0[1]) <= 1e-10 * abs(p0[1]), (p1, p0)
    e0, e1 = (float(diagnostics.total_energy(scene, params, s)) for s in (s0, final))
    assert abs(e1 / e0 - 1) < 0.02, e1 / e0
    # the air takes part: it is pushed and heated where the sphere went into the plate
    air = phase_slices(scene)[2]
    assert float(jnp.max(jnp.abs(final.v[air, 1]))) > 100.0


# --- the slow set: the full runs (6 us) at the coarsest resolution, one field for the solids ------------


@functools.lru_cache(maxsize=4)
def full_run(pressure, fields=1):
    kw = {} if pressure is None else {"chamber_pressure": pressure}
    scene = cloud(fields=fields, **kw)
    params, s0, final, hist = run(scene, n_out=12)
    return scene, params, s0, final, hist


def drag_estimate_distance(v0, t, pressure, d, c_drag=0.92):
    """Distance (m) flown in time t by a fragment of size d (m) that starts at v0 (m/s) through still
    chamber air: dv/dt = -(3/4) C_D rho_air v^2 / (rho_s d), so v = v0 / (1 + k v0 t) and the
    distance ln(1 + k v0 t) / k, k = (3/4) C_D rho_air / (rho_s d); C_D = 0.92, a sphere's drag
    coefficient at Mach 3-10 (Bailey & Hiatt, AIAA J. 10 (1972) 1436)."""
    rho_air = dict(chamber_air(pressure).constants)["rho0"]
    rho_s = library_constants("al2024")["rho0"]
    k = 0.75 * c_drag * rho_air / (rho_s * d)
    return np.log1p(k * v0 * t) / k


@pytest.mark.slow
def test_the_front_slows_in_the_dense_chamber_as_the_drag_estimate_says():
    """Point 1's velocity (slope over 3-6 us): at 0.1 bar all three features within 0.05 km/s of the
    vacuum run; at 10.5 bar the front slows more than at 0.1 bar, by a difference within a factor 2
    of the drag estimate for the leading fragments (size d = one cell: the run's leading debris on
    the axis is a layer 0.7-1.1 cells thick at 4-6 us; the estimate's front starts at the vacuum
    run's speed when it leaves the plate, 0.3 us). Measured: 0.44 km/s against 0.67 (ratio 0.66)."""
    vel = {}
    for p in (None, LOW, HIGH):
        scene, _, _, _, hist = full_run(p)
        vel[p] = -np.asarray(features.feature_velocities(scene, hist, first=6))
    print({k: (v / 1e3).round(3).tolist() for k, v in vel.items()})
    assert np.all(np.abs(vel[LOW] - vel[None]) < 50.0)
    slowed = vel[LOW][0] - vel[HIGH][0]
    assert slowed > 100.0
    scene, _, _, _, hist = full_run(None)
    t = np.asarray(hist.t)[6:] - 0.3e-6
    v_est = {p: np.polyfit(t, drag_estimate_distance(vel[None][0], t, p, scene.grid.h), 1)[0] for p in (LOW, HIGH)}
    est = v_est[LOW] - v_est[HIGH]
    print("front slowed", slowed, "estimate", est)
    assert 0.5 < slowed / est < 2.0


def shock_layer_density(scene, state, z_front):
    """The largest air density (kg/m^3) on the axis (r < 2 h) in one-cell slices from 8 cells ahead of
    the debris front up to the front (the lowest solid particle): the density behind the bow shock,
    which stands ahead of the front (sum of mass / sum of volume per slice). The air between the
    fragments behind the front is not the bow shock's and is left out."""
    h = scene.grid.h
    air = phase_slices(scene)[2]
    x, m, v = (np.asarray(a[air]) for a in (state.x, state.mass, state.volume))
    near = (x[:, 0] < 2 * h) & (x[:, 1] > z_front - 8 * h) & (x[:, 1] < z_front)
    slab = np.floor((x[near, 1] - z_front) / h).astype(int)
    return max(m[near][slab == k].sum() / v[near][slab == k].sum() for k in np.unique(slab))


@pytest.mark.slow
def test_a_bow_shock_forms_ahead_of_the_cloud_with_the_normal_shock_jump():
    """10.5 bar, each output from 2 to 6 us: the air ahead of the debris front (on the axis) is
    compressed by the bow shock. Between the shock and the front the exact density lies between the
    normal-shock jump of the front's speed, rho_2 / rho_1 = (gamma + 1) M^2 / ((gamma - 1) M^2 + 2)
    (Rankine-Hugoniot for an ideal gas), M = (front speed over the last two outputs) / c_air (M = 15,
    rho_2 / rho_1 = 5.87), and the stagnation density, 1.075 times that at M = 15 (the isentropic
    compression to rest behind the shock, (1 + (gamma - 1) / 2 M_2^2)^(1 / (gamma - 1)), M_2 the
    post-shock Mach number). The largest density ahead of the front must be within 20% of the normal-shock jump at every output (measured 0.93-1.11 at
    resolution 0.75, 0.94-1.16 at resolution 1). Still air 12 cells ahead of the front."""
    scene, params, _, final, hist = full_run(HIGH)
    h = scene.grid.h
    air = phase_slices(scene)[2]
    t = np.asarray(hist.t)
    z_front = np.array([float(jnp.min(at(hist, k).x[: air.start, 1])) for k in range(len(t))])
    c = library_constants("air")
    gamma = c["gamma"]
    rho0 = dict(chamber_air(HIGH).constants)["rho0"]
    ratios = []
    for k in np.flatnonzero(t >= 2e-6 - 1e-12):
        mach = -(z_front[k] - z_front[k - 2]) / (t[k] - t[k - 2]) / math.sqrt(gamma * c["R"] * c["T_room"])
        rh = (gamma + 1) * mach**2 / ((gamma - 1) * mach**2 + 2)
        ratios.append(shock_layer_density(scene, at(hist, k), z_front[k]) / rho0 / rh)
        x = np.asarray(at(hist, k).x[air])
        far = x[:, 1] < z_front[k] - 12 * h
        rho = np.asarray(at(hist, k).mass[air] / at(hist, k).volume[air])[far]
        assert np.abs(rho / rho0 - 1).max() < 0.05  # the shock has not run far ahead: still air beyond it
    print("bow shock density jump / Rankine-Hugoniot's, 2-6 us:", np.round(ratios, 3))
    assert np.all(np.abs(np.asarray(ratios) - 1) < 0.2), ratios


@pytest.mark.slow
def test_chamber_momentum_and_energy_over_the_run_with_the_drag_heat():
    """10.5 bar, three fields with the drag's heat, 6 us: mass exact, kinetic + internal energy within
    2%; axial momentum to 1e-10 relative up to 2.5 us, while the waves are inside (later the walls
    take momentum: 3e-4 of it by 6 us, one field for the solids)."""
    scene = cloud(fields=2, chamber_pressure=HIGH, drag_heating=True)
    params, s0, final, hist = run(scene, n_out=12)
    np.testing.assert_array_equal(np.asarray(final.mass), np.asarray(s0.mass))
    e = np.array([float(diagnostics.total_energy(scene, params, at(hist, k))) for k in range(len(hist.t))])
    assert np.abs(e / e[0] - 1).max() < 0.02, e / e[0]
    pz = np.array([float(diagnostics.momentum(at(hist, k))[1]) for k in range(len(hist.t))])
    inside = np.asarray(hist.t) <= 2.5e-6
    assert np.abs(pz[inside] / pz[0] - 1).max() < 1e-10, pz / pz[0] - 1


@pytest.mark.slow
def test_the_front_velocity_gradient_with_respect_to_log_drag_matches_central_differences():
    """d(point 1 velocity)/d log C_d at 10.5 bar by reverse mode against central differences (step
    1e-5 in log C_d), the whole chamber, one field for the solids, 1.5 us at a fixed step (the front
    over 0.75-1.5 us). Measured: reverse mode 2.8283794 m/s; central differences at steps 1e-2, 1e-3,
    1e-4, 1e-5: -116.8, 2.34, 2.8283801, 2.8283794. The front is a soft extreme over particles whose
    drag switches as they cross cells, so the finite differences need a step below 1e-4 to see the
    derivative: at 1e-3 they straddle such switches (on a plate of 6 mm radius, 1 us: 15.99, 15.34896,
    15.348501, 15.3484955 against 15.3484954)."""
    scene = cloud(chamber_pressure=HIGH, t_end=1.5e-6)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    dt = 0.5 * float(cfl_time_step(scene, params, s0))
    n = int(math.ceil(scene.t_end / dt))

    def front_velocity(log_cd):
        p = dataclasses.replace(params, drag_coefficient=jnp.exp(log_cd))
        _, hist = jaxmpm.simulate(scene, p, s0, t_end=n * dt, n_out=4, dt=dt, n_steps=n, progress=False)
        return features.feature_velocities(scene, hist, first=2)[0]

    g = float(jax.jit(jax.grad(front_velocity))(0.0))
    f = jax.jit(front_velocity)
    eps = 1e-5
    fd = (float(f(eps)) - float(f(-eps))) / (2 * eps)
    print("d v1 / d log C_d", g, "central differences", fd)
    assert abs(fd) > 1.0  # the drag acts on the front
    assert g == pytest.approx(fd, rel=1e-5)


def widened(scene, factor_r=2, extra_z=20e-3):
    """The same chamber in a grid `factor_r` times as wide and `extra_z` (m) taller (same cell size
    and origin, so the solids' particles are the same), the air filling it."""
    grid = dataclasses.replace(
        scene.grid, cells=(factor_r * scene.grid.cells[0], scene.grid.cells[1] + round(extra_z / scene.grid.h))
    )
    air = scene.phases[-1]
    chamber = Difference(Box(grid.origin, grid.hi), air.geometry.minus)
    return dataclasses.replace(
        scene, grid=grid, phases=scene.phases[:-1] + (dataclasses.replace(air, geometry=chamber),)
    )


@pytest.mark.slow
def test_the_walls_do_not_reach_the_cloud_within_the_run():
    """10.5 bar, 6 us: the same run in a grid twice as wide (36 mm against 18) and 20 mm taller. The
    bow shock's wings and the back-spray from the impact face reach the side and top walls from about
    2.5 us, but nothing they reflect reaches the cloud: the solids below the plate's top face end
    within 0.05 h of their place in the wider grid (measured 0.006 h), and points 1, 2 and 4 agree
    within 0.005 km/s (measured 1e-4). The particles that do differ are back-spray at the walls."""
    scene, _, s0, final, hist = full_run(HIGH)
    big = widened(scene)
    params_big, s0_big, final_big, hist_big = run(big, n_out=12)
    solids = phase_slices(scene)[2].start
    np.testing.assert_array_equal(np.asarray(s0_big.x[:solids]), np.asarray(s0.x[:solids]))
    x, x_big = np.asarray(final.x[:solids]), np.asarray(final_big.x[:solids])
    cloud_part = x[:, 1] < 0.0
    assert cloud_part.sum() > 0.5 * solids
    moved = np.linalg.norm(x - x_big, axis=1)[cloud_part].max() / scene.grid.h
    v = np.asarray(features.feature_velocities(scene, hist, first=6))
    v_big = np.asarray(features.feature_velocities(big, hist_big, first=6))
    print("cloud's largest shift / h", moved, "features", v / 1e3, v_big / 1e3)
    assert moved < 0.05
    np.testing.assert_allclose(v, v_big, atol=5.0)
