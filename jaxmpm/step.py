"""make_step(scene): the explicit MPM step composed from the stages the scene calls for.

    step(params, state, t_stop=inf, dt=None) -> state      (pure; jit, vmap and grad compose)

Stages (PHYSICS 2.1, ARCHITECTURE): 1 shape functions, 2 particle to grid, 3 grid update,
4 grid to particle with the seed's update and remap (or APIC), 5 constitutive update per phase.
Everything an effect needs is chosen here, in Python, before tracing: an effect the scene does not
name (gravity, damping, body force, DDMP, a wall) is not in the traced program at all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm import ddmp
from jaxmpm.materials.models import MODELS
from jaxmpm.shapes import ddmp_beta, stencil
from jaxmpm.state import particle_fields, phase_slices
from jaxmpm.transfer import cell_count, gather, interpolate, scatter


@dataclass(frozen=True)
class Layout:
    """Static facts of a scene that the traced step uses (numpy / Python only)."""

    scene: object
    dim: int
    n_fields: int
    n_nodes: int
    field: np.ndarray | None         # (N,) field index per particle, None with one field
    slices: tuple                    # per phase
    bc_mask: np.ndarray | None       # (n_nodes, d) 1 where a velocity component is free, None if no walls

    @staticmethod
    def of(scene) -> "Layout":
        K = scene.n_fields
        return Layout(scene=scene, dim=scene.dim, n_fields=K, n_nodes=scene.grid.n_nodes,
                      field=particle_fields(scene) if K > 1 else None,
                      slices=phase_slices(scene), bc_mask=boundary_mask(scene))


def boundary_mask(scene) -> np.ndarray | None:
    """(n_nodes, d) multiplier: 0 for components a wall holds (fixed: all; slip: normal), else 1."""
    g, b = scene.grid, scene.boundary
    if all(b.kind(k, s) == "free" for k in range(g.dim) for s in ("lo", "hi")):
        return None
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in g.nodes], indexing="ij"), -1).reshape(-1, g.dim)
    mask = np.ones((g.n_nodes, g.dim))
    for k in range(g.dim):
        for side in ("lo", "hi"):
            kind = b.kind(k, side)
            if kind == "free":
                continue
            near = idx[:, k] < b.layers if side == "lo" else idx[:, k] > g.cells[k] - b.layers
            if kind == "fixed":
                mask[near, :] = 0.0
            else:
                mask[near, k] = 0.0
    return mask


# ----------------------------------------------------------------------------------- helpers
def _safe_div(a, b, bmin):
    ok = b > bmin
    return jnp.where(ok, a / jnp.where(ok, b, 1.0), 0.0)


def _apply_bc(lay, v):
    return v if lay.bc_mask is None else v * jnp.asarray(lay.bc_mask, v.dtype)


def _mass_floor(state):
    eps = jnp.finfo(state.mass.dtype).eps
    return jnp.max(state.mass) * eps**2


def _grid_shape(lay):
    return (lay.n_fields,) + tuple(lay.scene.grid.nodes)


def gravity_now(params, t):
    """Gravity (d,) at time t, ramped smoothly over params.gravity_ramp: g (1 - cos(pi t / T)) / 2."""
    T = params.gravity_ramp
    on = T > 0
    r = 0.5 * (1 - jnp.cos(jnp.pi * jnp.clip(t / jnp.where(on, T, 1.0), 0.0, 1.0)))
    return params.gravity * jnp.where(on, r, 1.0)


def wave_speed(scene, params, state):
    """(N,) longitudinal wave speed of every particle (m/s) at its current density."""
    rho = state.mass / state.volume
    out = []
    for p, sl in zip(scene.phases, phase_slices(scene)):
        model = MODELS[scene.material(p).model]
        out.append(model.wave_speed(params.phases[p.name], rho[sl], scene.dim) * jnp.ones_like(rho[sl]))
    return jnp.concatenate(out)


def cfl_time_step(scene, params, state, cfl=None):
    """dt = CFL h / max_p (c_p + |v_p|) (PHYSICS 2.1), s."""
    cfl = params.cfl if cfl is None else cfl
    speed = wave_speed(scene, params, state) + jnp.linalg.norm(state.v, axis=-1)
    return cfl * scene.grid.h / jnp.max(speed)


# ----------------------------------------------------------------------------------- stages
def body_acceleration(lay, params, state):
    """(N, d) per-particle body acceleration from gravity and per-phase body forces (m/s^2), or None."""
    scene = lay.scene
    acc = None
    if scene.gravity is not None:
        acc = jnp.broadcast_to(gravity_now(params, state.t), state.v.shape)
    if scene.body_force:
        b = jnp.concatenate([jnp.broadcast_to(params.body_force[p.name], (sl.stop - sl.start, lay.dim))
                             for p, sl in zip(scene.phases, lay.slices)])
        acc = b if acc is None else acc + b
    return acc


def particle_to_grid(lay, st, state, beta):
    """Stage 2: one scatter of mass, momentum, force (and DDMP's nodal volume and stress share).
    Returns a dict of nodal arrays (K, n_nodes, ...)."""
    d = lay.dim
    m, v, V, sig = state.mass, state.v, state.volume, state.stress
    w = st.w[..., None]
    sig_p = V[:, None, None] * sig if beta is None else (V * beta)[:, None, None] * sig
    parts = [w * m[:, None, None], w * (m[:, None] * v)[:, None, :],
             -jnp.einsum("nab,nsb->nsa", sig_p, st.dw)]                           # (E11) first part
    if beta is not None:
        shv = ((V * (1 - beta))[:, None, None] * sig).reshape(-1, d * d)
        parts += [w * V[:, None, None], w * shv[:, None, :]]
    g = scatter(st, lay.field, jnp.concatenate(parts, -1), lay.n_fields, lay.n_nodes)
    out = {"m": g[..., 0], "mv": g[..., 1:1 + d], "f": g[..., 1 + d:1 + 2 * d]}
    if beta is not None:
        out["vol"] = g[..., 1 + 2 * d]
        out["shv"] = g[..., 2 + 2 * d:].reshape(g.shape[:-1] + (d, d))
    return out


def ddmp_operators(lay, st, nodal_volume, dtype):
    scene = lay.scene
    cells = cell_count(st, lay.field, lay.n_fields, math.prod(scene.grid.cells), dtype)
    return ddmp.build(scene.grid, nodal_volume.reshape(_grid_shape(lay)),
                      cells.reshape((lay.n_fields,) + scene.grid.cells))


def internal_force(lay, st, g, dtype):
    """Stage 3a: nodal internal force (K, n_nodes, d), adding DDMP's node-to-node part (E11)."""
    f = g["f"]
    if "shv" in g:
        dg = ddmp_operators(lay, st, g["vol"], dtype)
        shv = g["shv"].reshape(_grid_shape(lay) + (lay.dim, lay.dim))
        f = f + ddmp.nodal_stress_force(lay.scene.grid, dg, shv).reshape(f.shape)
    return f


def grid_acceleration(lay, params, state, st, g, acc_p, m_min):
    """Stage 3b: nodal velocity v (BC applied) and acceleration a = f / m + body - damping v."""
    m = g["m"][..., None]
    v = _apply_bc(lay, _safe_div(g["mv"], m, m_min))
    f = internal_force(lay, st, g, state.mass.dtype)
    if acc_p is not None:
        f = f + scatter(st, lay.field, st.w[..., None] * (state.mass[:, None] * acc_p)[:, None, :],
                        lay.n_fields, lay.n_nodes)
    a = _safe_div(f, m, m_min)
    if lay.scene.damping is not None:
        a = a - params.damping * v
    return v, _apply_bc(lay, a)


def particle_velocity_gradient(lay, st, v, nodal_volume=None):
    """L_p = sum_n v_n (x) grad S_n(x_p) for nodal velocities v (K, n_nodes, d); with DDMP
    (nodal_volume (K, n_nodes) = sum_p V_p S_np given) the blend (E12):
    L_p = beta_p sum_i v_i (x) grad S_i(x_p) + (1 - beta_p) sum_j S_j(x_p) L-bar_j. Returns (N, d, d)."""
    d = lay.dim
    L = jnp.einsum("nsa,nsb->nab", gather(st, lay.field, v), st.dw)
    if nodal_volume is None:
        return L
    beta = ddmp_beta(st.xi)
    dg = ddmp_operators(lay, st, nodal_volume, v.dtype)
    Lbar = ddmp.nodal_velocity_gradient(lay.scene.grid, dg, v.reshape(_grid_shape(lay) + (d,)))
    Lbar = interpolate(st, lay.field, Lbar.reshape(lay.n_fields, lay.n_nodes, d * d)).reshape(-1, d, d)
    return beta[:, None, None] * L + (1 - beta)[:, None, None] * Lbar                  # (E12)


def velocity_gradient(lay, st, state, m_min):
    """Stage 4b: remap the particle momentum onto the grid at the new positions (seed:
    m_n v_n = sum_p m_p v_p S_n(x_p^new)), walls applied, then L_p (N, d, d)."""
    d = lay.dim
    parts = [state.mass[:, None], state.mass[:, None] * state.v]
    ddmp_on = lay.scene.shape == "ddmp"
    if ddmp_on:
        parts.append(state.volume[:, None])
    g = scatter(st, lay.field, st.w[..., None] * jnp.concatenate(parts, -1)[:, None, :], lay.n_fields, lay.n_nodes)
    v = _apply_bc(lay, _safe_div(g[..., 1:1 + d], g[..., :1], m_min))
    return particle_velocity_gradient(lay, st, v, g[..., 1 + d] if ddmp_on else None)


def constitutive(lay, params, state, L, dt):
    """Stage 5: per phase, its model's stress update; volume V *= exp(dt tr L); internal energy
    de = dt V sigma:D / m with midpoint stress and volume."""
    scene = lay.scene
    Fs, sigs = [], []
    for p, sl in zip(scene.phases, lay.slices):
        model = MODELS[scene.material(p).model]
        F, sig = model.update(params.phases[p.name], state.F[sl], state.stress[sl], L[sl], dt)
        Fs.append(F)
        sigs.append(sig)
    F, sig = jnp.concatenate(Fs), jnp.concatenate(sigs)
    vol = state.volume * jnp.exp(dt * jnp.trace(L, axis1=1, axis2=2))
    D = 0.5 * (L + jnp.swapaxes(L, 1, 2))
    power = jnp.sum(0.5 * (sig + state.stress) * D, axis=(1, 2)) * 0.5 * (vol + state.volume)
    energy = state.energy + dt * power / state.mass
    return F, sig, vol, energy


def seed_update(lay, params, state, dt):
    """One step of the seed's update (PHYSICS 2.1 step 4) with linear, DDMP or B-spline gradients.

    v_p += dt sum_n a_n S_np; x_p += dt sum_n (v_n + h_a a_n dt) S_np; remap at the new positions;
    L_p from the remapped velocity; stress update. The seed's literal term h_a = 1/2
    (transfer = 'seed_halfstep') moves particles with a velocity other than the one whose gradient
    drives the stress, so positions and F drift apart at O(dt): on the vibrating bar (CFL 0.02,
    50 cells) its displacement error is 3.6e-7 m and first order in dt, while h_a = 1
    (transfer = 'seed', the default: positions and stress driven by the same v_old + a dt, a
    staggered leapfrog) gives 1.6e-8 m and second order in space (tests/test_vibrating_bar.py).
    """
    scene = lay.scene
    m_min = _mass_floor(state)
    st = stencil(scene, state.x)                                                   # 1
    beta = ddmp_beta(st.xi) if scene.shape == "ddmp" else None
    g = particle_to_grid(lay, st, state, beta)                                     # 2
    acc_p = body_acceleration(lay, params, state)
    v_n, a_n = grid_acceleration(lay, params, state, st, g, acc_p, m_min)          # 3
    # 4: seed_halfstep moves particles with v_old + a dt / 2 (the seed's literal term); seed moves them
    # with v_old + a dt, the velocity whose gradient drives the stress (second order; see seed_update).
    half = 0.5 if scene.transfer == "seed_halfstep" else 1.0
    va = interpolate(st, lay.field, jnp.concatenate([a_n, v_n + half * dt * a_n], -1))
    d = lay.dim
    v = state.v + dt * va[:, :d]
    x = state.x + dt * va[:, d:]
    moved = replace(state, x=x, v=v)
    st2 = stencil(scene, x)
    L = velocity_gradient(lay, st2, moved, m_min)
    F, sig, vol, energy = constitutive(lay, params, moved, L, dt)                  # 5
    return replace(moved, t=state.t + dt, F=F, stress=sig, volume=vol, energy=energy)


def apic_update(lay, params, state, dt):
    """APIC / MLS-MPM step with quadratic B-splines (D^-1 = 4 / h^2), for the peers' scene."""
    scene = lay.scene
    d, h = lay.dim, scene.grid.h
    dinv = 4.0 / h**2
    m_min = _mass_floor(state)
    st = stencil(scene, state.x)
    m, V = state.mass, state.volume
    affine = (m[:, None, None] * state.C) - dt * dinv * V[:, None, None] * state.stress  # MLS force folded in
    mom = st.w[..., None] * (m[:, None] * state.v)[:, None, :] + st.w[..., None] * jnp.einsum("nab,nsb->nsa", affine, st.dpos)
    acc_p = body_acceleration(lay, params, state)
    if acc_p is not None:
        mom = mom + dt * st.w[..., None] * (m[:, None] * acc_p)[:, None, :]
    g = scatter(st, lay.field, jnp.concatenate([st.w[..., None] * m[:, None, None], mom], -1), lay.n_fields, lay.n_nodes)
    v_n = _safe_div(g[..., 1:], g[..., :1], m_min)
    if scene.damping is not None:
        v_n = v_n * jnp.exp(-params.damping * dt)
    v_n = _apply_bc(lay, v_n)
    vs = gather(st, lay.field, v_n)
    v = jnp.sum(st.w[..., None] * vs, 1)
    C = dinv * jnp.einsum("ns,nsa,nsb->nab", st.w, vs, st.dpos)
    moved = replace(state, x=state.x + dt * v, v=v, C=C)
    F, sig, vol, energy = constitutive(lay, params, moved, C, dt)
    return replace(moved, t=state.t + dt, F=F, stress=sig, volume=vol, energy=energy)


def make_step(scene):
    """Compose the pure step of `scene`: step(params, state, t_stop=inf, dt=None) -> state.

    dt defaults to the CFL step (PHYSICS 2.1); it is clipped so that t never passes t_stop, and a
    step with dt = 0 returns the state unchanged (so a fixed-length scan stays differentiable).
    """
    lay = Layout.of(scene)
    update = apic_update if scene.transfer == "apic" else seed_update

    def step(params, state, t_stop=jnp.inf, dt=None):
        dt = cfl_time_step(scene, params, state) if dt is None else jnp.asarray(dt, state.t.dtype)
        dt = jnp.clip(jnp.minimum(dt, t_stop - state.t), 0.0, None)
        active = dt > 0
        new = update(lay, params, state, dt)
        return jax.tree.map(lambda a, b: jnp.where(active, a, b), new, state)

    return step
