"""Stage 4 of the step (PHYSICS 2.1): grid to particle, for the seed's update and remap
(transfer 'musl', 'seed', 'seed_halfstep'): the particles' velocity and position from the grid
stage's `GridUpdate`, the remap of their momentum to the grid with the exchange on it (E14), the
drag's heat, the velocity gradient the constitutive stage takes (with the DDMP operator, E12, and
the hoop rate of axisymmetric scenes) and, with 'musl' and a hydrocode phase, the gradient the
grid's forces did work with (`force_work_velocity`).

Shapes: N particles, K velocity fields, n nodes, d dimensions; SI units.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.numerics import ddmp
from jaxmpm.numerics.shapes import Stencil, ddmp_beta, stencil
from jaxmpm.numerics.transfer import gather, interpolate, scatter, stencil_outer
from jaxmpm.stages import fields
from jaxmpm.stages.density_diffusion import density_diffusion_rate, diffused_particles
from jaxmpm.stages.layout import Layout, apply_walls
from jaxmpm.stages.multifield import ambient_pressure_by_phase, exchange_force
from jaxmpm.stages.nodal import GridUpdate, NodalSums, ddmp_operators, grid_shape, particle_radius, scatter_named
from jaxmpm.stages.phase_models import has_hydro


def grid_to_particle(
    layout: Layout,
    params: Params,
    state: State,
    stencils: Stencil,
    beta: jax.Array | None,
    sums: NodalSums,
    grid: GridUpdate,
    dt: jax.Array,
    m_min: jax.Array,
) -> tuple[State, jax.Array, jax.Array | None, jax.Array | None]:
    """Stage 4: (moved, L, p_amb, L_work): the State with the particles' new x, v (and energy, with
    drag_heating), the velocity gradient L (N, d, d) (3 x 3 axisymmetric) that drives their
    constitutive update, the closure's ambient pressure at the particles (N,) Pa (E8) or None, and
    the gradient the grid's forces did work with (`force_work_velocity`; 'compatible' with a
    hydrocode phase, else None). stencils, beta, g: the step's stencil, DDMP blend and particle-to-grid
    scatter (stages 1, 2)."""
    scene = layout.scene
    d = layout.dim
    v_n, a_n, operators, p_amb_n, volume_rate, impulses = grid
    p_amb = None if p_amb_n is None else interpolate(stencils, layout.field, p_amb_n[..., None])[:, 0]
    if scene.has_closure and layout.n_phases > 1 and not layout.ambient_by_field:
        p_amb = ambient_pressure_by_phase(layout, params, stencils, state)  # (E8)
    L_work = None
    if scene.transfer == "musl":
        v = state.v + dt * interpolate(stencils, layout.field, a_n)
        vol_n = sums.volume[..., 0] if sums.volume is not None else None
        with jax.named_scope("remap"):
            v_r = remap_exchange(layout, params, stencils, state, v, vol_n, dt, m_min, raw=impulses is not None)
        energy = state.energy
        if impulses is not None:  # the drag's work as heat (drag_heating), by mass: sum_p m_p de_p = sum_n Q_nk
            v_r, v_raw = v_r
            m = sums.mass[..., 0]
            heat = fields.drag_heat(impulses, m, v_raw, m_min)
            energy = energy + interpolate(stencils, layout.field, fields.safe_div(heat, m, m_min)[..., None])[:, 0]
        x = state.x + dt * interpolate(stencils, layout.field, v_r)
        with jax.named_scope("velocity_gradient"):
            L, L_work = musl_velocity_gradients(
                layout, params, state, stencils, operators, vol_n if beta is not None else None, v_n, v_r, volume_rate
            )
        moved = replace(state, x=x, v=v, energy=energy)
    else:
        half = 0.5 if scene.transfer == "seed_halfstep" else 1.0
        va = interpolate(stencils, layout.field, jnp.concatenate([a_n, v_n + half * dt * a_n], -1))
        moved = replace(state, x=state.x + dt * va[:, d:], v=state.v + dt * va[:, :d])
        with jax.named_scope("velocity_gradient"):
            L = velocity_gradient(layout, params, stencil(scene, moved.x), moved, dt, m_min)
    return moved, L, p_amb, L_work


def musl_velocity_gradients(
    layout: Layout,
    params: Params,
    state: State,
    stencils: Stencil,
    operators: ddmp.DDMPGrid | None,
    nodal_volume: jax.Array | None,
    v_n: jax.Array,
    v_r: jax.Array,
    volume_rate: Callable[[jax.Array], jax.Array] | None,
) -> tuple[jax.Array, jax.Array | None]:
    """(L, L_work) of a 'musl' step, (N, d, d) 1/s each: L the velocity gradient of the remapped
    nodal velocity v_r (K, n, d), with the continuity form's volume rate (E7) and the fluids' density
    diffusion added to its trace; L_work the same of `force_work_velocity`(v_n, v_r), the gradient
    the grid's forces did work with, where energy_update = 'compatible' and a phase is a hydrocode
    model, else None. nodal_volume: DDMP's (K, n), or None."""
    radius = particle_radius(layout, state)

    def isotropic(rate, L):  # rate (N,) 1/s added to the trace of L
        return L + (rate / L.shape[-1])[:, None, None] * jnp.eye(L.shape[-1], dtype=L.dtype)

    def of_velocity(v):  # the gradient and E7's rate, both linear in the nodal velocity v
        L = particle_velocity_gradient(layout, stencils, v, nodal_volume, operators, radius=radius)
        return isotropic(volume_rate(v), L) if layout.scene.continuity_form == "transport" else L  # (E7)

    L = of_velocity(v_r)
    L_work = None
    if layout.scene.energy_update == "compatible" and has_hydro(layout):
        L_work = of_velocity(force_work_velocity(v_n, v_r))
    fluid = diffused_particles(layout)
    if fluid is not None:
        rate = density_diffusion_rate(layout, params, stencils, state, fluid)
        L = isotropic(rate, L)
        L_work = None if L_work is None else isotropic(rate, L_work)
    return L, L_work


def force_work_velocity(v_start: jax.Array, v_end: jax.Array) -> jax.Array:
    """(K, n, d) m/s: the nodal velocity whose gradient, with the start stress, is the work the
    grid's forces did over a 'musl' step: the midpoint (v_n + v_n^new) / 2 of the start nodal
    velocity and the remap of the new particle velocities at the same positions (both with the
    walls applied). The step's kinetic energy changes by exactly sum_n f_n . (v_n + v_n^new) / 2 dt
    (f_n from sigma^n; sum_p m_p v_p . a_p = sum_n m_n v_n . a_n and sum_p m_p |a_p|^2 =
    sum_n m_n a_n . a-tilde_n), and sum_n f_n . u_n = - sum_p V_p sigma_p : L_p[u] because the force
    and the gradient are adjoint (E11/E12; E7's rate is the interface forces' transpose). So an
    internal energy that takes de = dt V^n sigma^n : sym(L[this]) / m makes the total exact, as in
    compatible hydrodynamics (Caramana et al., J. Comput. Phys. 146 (1998) 227); the midpoint stress
    on the end gradient gains energy at every strong impact."""
    return 0.5 * (v_start + v_end)


def _with_hoop(layout, stencils, L, v, radius):
    """Axisymmetric: L (N, 2, 2) of (r, z) -> (N, 3, 3) with L_thth = v_r(x_p) / r_p."""
    if radius is None:
        return L
    v_r = interpolate(stencils, layout.field, v[..., :1])[:, 0]
    L3 = jnp.zeros(L.shape[:-2] + (3, 3), L.dtype).at[:, :2, :2].set(L)
    return L3.at[:, 2, 2].set(v_r / radius)


def particle_velocity_gradient(
    layout: Layout,
    stencils: Stencil,
    v: jax.Array,
    nodal_volume: jax.Array | None = None,
    operators: ddmp.DDMPGrid | None = None,
    volume: jax.Array | None = None,
    radius: jax.Array | None = None,
) -> jax.Array:
    """L_p = sum_n v_n (x) grad S_n(x_p) for nodal velocities v (K, n_nodes, d); with DDMP
    (nodal_volume (K, n_nodes) = sum_p V_p S_np given, with the operators operators or the particle
    volumes (N,) to build them) the blend (E12):
    L_p = beta_p sum_i v_i (x) grad S_i(x_p) + (1 - beta_p) sum_j S_j(x_p) L-bar_j. Returns (N, d, d)."""
    d = layout.dim
    L = stencil_outer(gather(stencils, layout.field, v), stencils.dw)
    if nodal_volume is None:
        return _with_hoop(layout, stencils, L, v, radius)
    beta = ddmp_beta(stencils.xi)
    operators = ddmp_operators(layout, stencils, nodal_volume, v.dtype, volume) if operators is None else operators
    Lbar = ddmp.nodal_velocity_gradient(layout.scene.grid, operators, v.reshape(grid_shape(layout) + (d,)))
    Lbar = interpolate(stencils, layout.field, Lbar.reshape(layout.n_fields, layout.n_nodes, d * d)).reshape(-1, d, d)
    return _with_hoop(layout, stencils, beta[:, None, None] * L + (1 - beta)[:, None, None] * Lbar, v, radius)  # (E12)


def velocity_gradient(
    layout: Layout, params: Params, stencils: Stencil, state: State, dt: ArrayLike, m_min: ArrayLike
) -> jax.Array:
    """Stage 4b of the 'seed' variants: remap at the new positions (with E14 between coupled
    fields), then L_p (N, d, d) there."""
    ddmp_on = layout.scene.shape == "ddmp"
    vol_n = None
    if ddmp_on or layout.scene.has_exchange:
        vol_n = layout.particle_sum(
            scatter(
                stencils,
                layout.field,
                stencils.w[..., None] * state.volume[:, None, None],
                layout.n_fields,
                layout.n_nodes,
            )
        )[..., 0]
    v = remap_exchange(layout, params, stencils, state, state.v, vol_n, dt, m_min)
    return particle_velocity_gradient(
        layout, stencils, v, vol_n if ddmp_on else None, volume=state.volume, radius=particle_radius(layout, state)
    )


def remap_exchange(
    layout: Layout,
    params: Params,
    stencils: Stencil,
    state: State,
    v_p: jax.Array,
    vol_n: jax.Array | None,
    dt: ArrayLike,
    m_min: ArrayLike,
    raw: bool = False,
) -> jax.Array | tuple[jax.Array, jax.Array]:
    """Remap particle velocities v_p onto the nodes of stencil stencils: v_n = sum m_p v_p S_np / m_n,
    walls applied; with several coupled fields the implicit exchange applied again (E14).
    vol_n: nodal volume (K, n_nodes) for the exchange (or None). Returns (K, n_nodes, d); raw=True:
    (that, the remapped velocity before E14)."""
    w = stencils.w[..., None]
    sums = scatter_named(
        layout,
        stencils,
        {"mass": w * state.mass[:, None, None], "momentum": w * (state.mass[:, None] * v_p)[:, None, :]},
    )
    v = v_raw = apply_walls(layout, fields.safe_div(sums.momentum, sums.mass, m_min))
    if layout.scene.has_exchange:  # (E14)
        F = exchange_force(layout, params, sums.mass[..., 0], vol_n, v, dt, m_min)
        # under lax.cond(dt > 0), like the exchange (at dt = 0 the update adds nothing): XLA keeps
        # the updated v as one array where it fused its masks and divisions into DDMP's velocity
        # gradient (E12) and repeated them for each of a cell's 16 outputs (the debris cloud's E12
        # 0.40 -> 0.21 ms per step; its forward step and gradient 8-10% faster, interleaved)
        v = jax.lax.cond(dt > 0, lambda: apply_walls(layout, v + dt * fields.safe_div(F, sums.mass, m_min)), lambda: v)
    return (v, v_raw) if raw else v
