"""A 2D axisymmetric Eulerian finite-volume hydrocode, independent of jaxmpm's discretisation: the
reference for the debris cloud's hydrodynamics (docs/closure.md). It solves the compressible Euler
equations (no strength) with the Mie-Grueneisen equation of state of tests/spherical_lagrangian.py
on a fixed grid of square cells of side h, in (r, z):

    d(r U)/dt + d(r F)/dr + d(r G)/dz = (0, p, 0, 0, 0, ...),
    U = (rho, rho u_r, rho u_z, E, rho phi_1, ...),  E = rho (e + |u|^2 / 2),
    F = u_r U + (0, p, 0, p u_r, 0, ...),  G = u_z U + (0, 0, p, p u_z, 0, ...),

phi_k the mass fractions of the bodies (passive tracers: which material is where). Cells hold the
averages of U; fluxes by HLL (Davis's wave speeds) between states reconstructed linearly in
(rho, u_r, u_z, e, phi) with minmod slopes; time by SSP-RK2 (Heun), the step dt = cfl / max((|u_r| +
c) / h + (|u_z| + c) / h). No artificial viscosity: the Riemann fluxes capture the shocks. The axis is
a mirror (u_r odd), the other edges let material out. Void is the material at 1e-3 rho0 and p = 0;
the pressure is floored at p_min (0: no tension, a fragmenting metal's limit). With p = A(rho) +
B(rho) e the sound speed is c^2 = A' + B' e + B p / rho^2 (0 where the floor holds: dust).

Checked against the exact planar release (`planar_free_surface`: the rear face of a plate shocked by
a flyer of the same aluminium at 6.71 km/s leaves at 6.895 km/s; 7.068, 6.941, 6.913, 6.902 km/s on
cells of 0.2, 0.1, 0.05 and 0.025 mm)."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from spherical_lagrangian import mie_gruneisen_ab

jax.config.update("jax_enable_x64", True)

VOID = 1e-3  # void's density over rho0
RHO_FLOOR = 1e-6  # the smallest density over rho0


def pressure_and_sound(c: dict, rho, e, p_min: float):
    """(p in Pa, c in m/s) of density rho (kg/m^3) and specific internal energy e (J/kg; negative e
    counts as 0), arrays of one shape; p is floored at p_min (Pa)."""
    ones = jnp.ones_like(rho)
    (a, b), (da, db) = jax.jvp(lambda x: mie_gruneisen_ab(c, x, jnp), (rho,), (ones,))
    e = jnp.maximum(e, 0.0)
    p = a + b * e
    c2 = jnp.where(p > p_min, jnp.maximum(da + db * e + b * p / rho**2, 0.0), 0.0)
    return jnp.maximum(p, p_min), jnp.sqrt(c2)


def primitives(c: dict, U):
    """(rho, u_r, u_z, e, phi...) of the conserved U, shape (4 + tracers, nr, nz)."""
    rho = jnp.maximum(U[0], RHO_FLOOR * c["rho0"])
    ur, uz = U[1] / rho, U[2] / rho
    e = U[3] / rho - 0.5 * (ur**2 + uz**2)
    return jnp.concatenate([jnp.stack([rho, ur, uz, e]), jnp.clip(U[4:] / rho, 0.0, 1.0)])


def conserved(W):
    """The conserved U of the primitives W = (rho, u_r, u_z, e, phi...), shape (4 + tracers, nr, nz)."""
    rho, ur, uz, e = W[:4]
    return jnp.concatenate([jnp.stack([rho, rho * ur, rho * uz, rho * (e + 0.5 * (ur**2 + uz**2))]), rho * W[4:]])


def _minmod(a, b):
    return jnp.where(a * b > 0, jnp.sign(a) * jnp.minimum(jnp.abs(a), jnp.abs(b)), 0.0)


def _with_ghosts(W):
    """Two ghost layers on each side: the axis r = 0 mirrors (u_r odd); the other edges copy."""
    mirror = W[:, 1::-1, :] * jnp.ones(W.shape[0]).at[1].set(-1.0)[:, None, None]
    W = jnp.concatenate([mirror, W, W[:, -1:], W[:, -1:]], axis=1)
    return jnp.concatenate([W[:, :, :1], W[:, :, :1], W, W[:, :, -1:], W[:, :, -1:]], axis=2)


def _face_states(Wg, axis: int):
    """Left and right states at the n + 1 faces along `axis` of Wg (two ghosts each side)."""
    n = Wg.shape[axis] - 4
    cut = functools.partial(jax.lax.slice_in_dim, Wg, axis=axis)
    centre = cut(1, n + 3)
    slope = _minmod(centre - cut(0, n + 2), cut(2, n + 4) - centre)
    left = jax.lax.slice_in_dim(centre + 0.5 * slope, 0, n + 1, axis=axis)
    right = jax.lax.slice_in_dim(centre - 0.5 * slope, 1, n + 2, axis=axis)
    return left, right


def _hll(c: dict, WL, WR, normal: int, p_min: float):
    """HLL flux through faces whose normal is velocity component `normal` (1: r, 2: z)."""

    def side(W):
        p, sound = pressure_and_sound(c, W[0], W[3], p_min)
        un = W[normal]
        U = conserved(W)
        return U, (U * un).at[normal].add(p).at[3].add(p * un), un, sound

    UL, FL, uL, cL = side(WL)
    UR, FR, uR, cR = side(WR)
    sl = jnp.minimum(jnp.minimum(uL - cL, uR - cR), 0.0)
    sr = jnp.maximum(jnp.maximum(uL + cL, uR + cR), 0.0)
    return (sr * FL - sl * FR + sl * sr * (UR - UL)) / jnp.where(sr > sl, sr - sl, 1.0)


def rate(c: dict, U, h: float, p_min: float):
    """dU/dt (U's units per s) of the finite-volume form, U (4 + tracers, nr, nz) on cells of side h (m),
    cell (i, j) at r_i = (i + 1/2) h, faces at i h."""
    W = primitives(c, U)
    Wg = _with_ghosts(W)
    F = _hll(c, *_face_states(Wg[:, :, 2:-2], 1), 1, p_min)
    G = _hll(c, *_face_states(Wg[:, 2:-2, :], 2), 2, p_min)
    r_face = jnp.arange(F.shape[1], dtype=jnp.float64)[:, None] * h
    r_cell = r_face[:-1] + 0.5 * h
    rF = F * r_face
    p, _ = pressure_and_sound(c, W[0], W[3], p_min)
    dU = -(rF[:, 1:] - rF[:, :-1]) / (r_cell * h) - (G[:, :, 1:] - G[:, :, :-1]) / h
    return dU.at[1].add(p / r_cell)  # the hoop pressure p / r


def stable_step(c: dict, U, h: float, p_min: float, cfl: float):
    """The time step (s) the CFL number `cfl` allows on cells of side h (m)."""
    W = primitives(c, U)
    _, sound = pressure_and_sound(c, W[0], W[3], p_min)
    return cfl / jnp.max((jnp.abs(W[1]) + jnp.abs(W[2]) + 2 * sound) / h)


@functools.partial(jax.jit, static_argnames=("c_items",))
def _advance(U, t, t_stop, h, p_min, cfl, c_items):
    c = dict(c_items)

    def step(carry):
        U, t = carry
        dt = jnp.minimum(stable_step(c, U, h, p_min, cfl), t_stop - t)
        U1 = U + dt * rate(c, U, h, p_min)
        U2 = 0.5 * (U + U1 + dt * rate(c, U1, h, p_min))
        return U2.at[0].set(jnp.maximum(U2[0], RHO_FLOOR * c["rho0"])), t + dt

    return jax.lax.while_loop(lambda carry: carry[1] < t_stop, step, (U, t))


def advance(c: dict, U, t: float, t_stop: float, h: float, p_min: float = 0.0, cfl: float = 0.4):
    """U and t advanced from t to t_stop (s)."""
    return _advance(U, jnp.asarray(t), jnp.asarray(t_stop), h, p_min, cfl, tuple(sorted(c.items())))


def cell_fractions(nr: int, nz: int, h: float, z_lo: float, inside, sub: int = 4) -> np.ndarray:
    """(nr, nz) volume fraction of each cell inside the set inside(r, z), by sub x sub points per
    cell weighted by r."""
    s = (np.arange(sub) + 0.5) / sub
    r = ((np.arange(nr)[:, None] + s) * h)[:, None, :, None]
    z = (z_lo + (np.arange(nz)[:, None] + s) * h)[None, :, None, :]
    weight = np.broadcast_to(r, (nr, nz, sub, sub))
    return (inside(r, z) * weight).sum((2, 3)) / weight.sum((2, 3))


def bodies(c: dict, h: float, r_max: float, z_lo: float, z_hi: float, shapes, velocities):
    """Conserved U of bodies at rest or moving along z in void: shapes are inside(r, z) tests,
    velocities their u_z (m/s). One tracer per body, in that order. -> (U, z of the cell centres)."""
    nr, nz = round(r_max / h), round((z_hi - z_lo) / h)
    f = np.stack([cell_fractions(nr, nz, h, z_lo, shape) for shape in shapes])
    rho = c["rho0"] * (f.sum(0) + VOID * (1 - f.sum(0)))
    uz = c["rho0"] * np.tensordot(np.asarray(velocities, float), f, axes=1) / rho
    W = np.concatenate([np.stack([rho, 0 * rho, uz, 0 * rho]), c["rho0"] * f / rho])
    return conserved(jnp.asarray(W)), z_lo + (np.arange(nz) + 0.5) * h


def leading_mass(mass: np.ndarray, budget: float) -> np.ndarray:
    """How much of each item's mass (in the order given) the first `budget` kg take: the items in
    front whole, the one that crosses the budget in part, the rest none."""
    before = np.concatenate([[0.0], np.cumsum(mass)[:-1]])
    return np.clip(budget - before, 0.0, mass)


def axial_slice(U, h: float, z: np.ndarray, tracer: int, r_axis: float, depth: float, rho0: float, top=False):
    """The leading (or, top, trailing) part of body `tracer`'s mass within r_axis of the axis: the
    areal mass rho0 * depth of that column, taken from the lowest (highest) z on. -> (its mass-weighted
    u_z, m/s; its mass-weighted z, m)."""
    U = np.asarray(U)
    r = (np.arange(U.shape[1]) + 0.5) * h
    weight = np.where(r < r_axis, r, 0.0)[:, None]
    mass = (U[4 + tracer] * weight).sum(0)
    momentum = (U[4 + tracer] / np.maximum(U[0], 1e-300) * U[2] * weight).sum(0)
    order = slice(None, None, -1) if top else slice(None)
    mass, momentum, z = mass[order], momentum[order], z[order]
    taken = leading_mass(mass, rho0 * depth / h * weight.sum())  # mass per row: sum of rho r
    share = taken / np.where(mass > 0, mass, 1.0)
    return (momentum * share).sum() / taken.sum(), (z * taken).sum() / taken.sum()


def mass_front(U, h: float, z: np.ndarray, fraction: float) -> float:
    """z (m) below which `fraction` of the bodies' mass lies, at any radius."""
    U = np.asarray(U)
    r = (np.arange(U.shape[1]) + 0.5) * h
    profile = (U[4:].sum(0) * r[:, None]).sum(0)
    return float(np.interp(fraction, np.cumsum(profile) / profile.sum(), z))


def planar_free_surface(c: dict, h: float, thickness: float = 2.21e-3, speed: float = 6710.0) -> float:
    """The rear face's speed (m/s) of a plate shocked by a flyer 10 mm thick of the same material:
    the slope of the mean z of the plate's rearmost 0.1 mm over 0.5-1.5 us (the shock arrives at 0.23 us;
    4 columns of cells with copied outer edge: planar)."""
    z_lo = -(thickness + 1.5e-6 * 7.5e3 + 1e-3)
    flyer = lambda r, z: (z > 0) & (z < 10e-3) & (r >= 0)  # noqa: E731
    plate = lambda r, z: (z < 0) & (z > -thickness) & (r >= 0)  # noqa: E731
    U, z = bodies(c, h, 4 * h, z_lo, 11e-3, (flyer, plate), (-speed, 0.0))
    times, fronts, t = np.arange(0.5e-6, 1.5e-6 + 1e-12, 0.05e-6), [], 0.0
    for t_out in times:
        U, t = advance(c, U, t, t_out, h)
        fronts.append(axial_slice(U, h, z, 1, 1.0, 0.1e-3, c["rho0"])[1])
    return -float(np.polyfit(times, fronts, 1)[0])


def debris_cloud(
    c: dict,
    h: float,
    t_end: float = 6e-6,
    every: float = 0.1e-6,
    radius: float = 9.53e-3 / 2,
    thickness: float = 2.21e-3,
    speed: float = 6710.0,
    r_max: float = 24e-3,
):
    """The debris cloud's impact (a sphere at `speed` on a plate, both of the material c, the sphere
    touching the plate's top face z = 0 at t = 0), outputs every `every` to t_end. -> dict of arrays
    over the outputs: t; 'plate' and 'projectile_front' (the leading 0.3 mm of the plate's and of the
    projectile's material within 1 mm of the axis), 'projectile_rear' (the trailing 0.3 mm of the
    projectile's there): each its mass-weighted u_z (m/s); 'front' the z below which 1e-4 of all mass lies;
    'U' the conserved fields at t_end (tracers: plate, projectile), 'z' the cells' centres (m), 'wall' (s)."""
    import time

    start = time.perf_counter()
    sphere = lambda r, z: r**2 + (z - radius) ** 2 < radius**2  # noqa: E731
    plate = lambda r, z: (z < 0) & (z > -thickness) & (r >= 0)  # noqa: E731
    z_lo = -(thickness + speed * t_end + 4e-3)
    U, z = bodies(c, h, r_max, z_lo, 2 * radius + 1e-3, (plate, sphere), (0.0, -speed))
    out = {k: [] for k in ("t", "plate", "projectile_front", "projectile_rear", "front")}
    t = 0.0
    for t_out in np.arange(every, t_end + 1e-12, every):
        U, t = advance(c, U, t, t_out, h)
        out["t"].append(float(t))
        out["plate"].append(axial_slice(U, h, z, 0, 1e-3, 0.3e-3, c["rho0"])[0])
        out["projectile_front"].append(axial_slice(U, h, z, 1, 1e-3, 0.3e-3, c["rho0"])[0])
        out["projectile_rear"].append(axial_slice(U, h, z, 1, 1e-3, 0.3e-3, c["rho0"], top=True)[0])
        out["front"].append(mass_front(U, h, z, 1e-4))
    wall = time.perf_counter() - start
    return {k: np.asarray(v) for k, v in out.items()} | {"U": np.asarray(U), "z": z, "wall": wall}


def hydrodynamic_debris_cloud(resolution: float):
    """jaxmpm's debris cloud scene with the hydrodynamic model that the reference solves (no
    strength, no closure, no tension: `mie_gruneisen+spall` with sigma_spall = 1 Pa)."""
    import jaxmpm
    from jaxmpm.materials import library_material

    scene = jaxmpm.load_scene("debris_cloud", resolution=resolution, fields=1, fragmentation="tensile")
    al = library_material("al2024", model="mie_gruneisen+spall", sigma_spall=1.0)
    return dataclasses.replace(scene, materials=(al,), c_h=None)


def mpm_axial_slices(scene) -> dict:
    """`debris_cloud`'s measures on jaxmpm's particles (a debris cloud scene, one run to its t_end
    with 60 outputs): {name: (outputs,) u_z in m/s}, 't' the times after the contact (s), 'front'
    the cloud's front (point 1's soft minimum, m) and 'wall' the run's wall time (s)."""
    import time

    import jaxmpm
    from jaxmpm.features import soft_min
    from jaxmpm.model.state import phase_slices
    from jaxmpm.scenes import initial_state

    params = jaxmpm.default_params(scene)
    s0 = initial_state(scene, params)
    sphere = scene.phases[0].geometry
    gap = sphere.center[1] - sphere.radius  # the sphere starts `gap` above the plate
    start = time.perf_counter()
    _, hist = jaxmpm.simulate(scene, params, s0, t_end=scene.t_end, n_out=60, progress=False)
    wall = time.perf_counter() - start
    x, v, m = (np.asarray(a) for a in (hist.x, hist.v, hist.mass))
    projectile, plate = phase_slices(scene)
    x0, m0 = np.asarray(s0.x), np.asarray(s0.mass)
    thickness = -scene.phases[1].geometry.lo[1]  # the plate's top face is z = 0
    column = m0[plate][x0[plate, 0] < 1e-3].sum() / thickness  # kg per m of depth within 1 mm of the axis

    def leading(k, part, top=False):
        near = x[k, part, 0] < 1e-3
        z, vz, mm = x[k, part, 1][near], v[k, part, 1][near], m[k, part][near]
        order = np.argsort(-z if top else z)
        taken = leading_mass(mm[order], column * 0.3e-3)
        return (vz[order] * taken).sum() / taken.sum()

    out = {
        "plate": [leading(k, plate) for k in range(len(x))],
        "projectile_front": [leading(k, projectile) for k in range(len(x))],
        "projectile_rear": [leading(k, projectile, top=True) for k in range(len(x))],
    }
    arrival = gap / abs(scene.phases[0].velocity[1])  # the contact's time: the reference starts at contact
    front = [float(soft_min(hist.x[k, :, 1], hist.mass[k], 0.1 * scene.grid.h)) for k in range(len(x))]
    return {k: np.asarray(val) for k, val in out.items()} | {
        "t": np.asarray(hist.t) - arrival,
        "front": np.asarray(front),
        "wall": wall,
        "x": x[-1],
        "is_plate": (np.arange(x.shape[1]) >= plate.start) & (np.arange(x.shape[1]) < plate.stop),
    }
