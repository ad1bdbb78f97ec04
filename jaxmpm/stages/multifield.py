"""The multi-velocity stage: what couples the velocity fields at the nodes. The phases' pressures
and compressibilities, the common pressure (E6) from nodal phase pressures (the E15 fit, or the
V_p S_np averages of the continuity form), the interface forces (E13), the continuity form's
volume rate (E7, the transpose of E13) and the implicit exchange (E3).

Shapes: N particles, K velocity fields, n_nodes nodes per field, d dimensions; `layout` is a
jaxmpm.stages.layout.Layout. SI units.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike, DTypeLike

from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.numerics import ddmp
from jaxmpm.numerics.shapes import Stencil
from jaxmpm.numerics.transfer import interpolate
from jaxmpm.stages import fields
from jaxmpm.stages.ambient import absolute_pressure, gauge_pressure
from jaxmpm.stages.closure import grid_pressure
from jaxmpm.stages.layout import Layout
from jaxmpm.stages.nodal import NodalSums, node_volume, particle_radius, pressure_parts, scatter_named
from jaxmpm.stages.phase_models import bulk_modulus_and_wave_speed


def phase_pressure_and_compressibility(layout: Layout, params: Params, state: State) -> tuple[jax.Array, jax.Array]:
    """(N,) particle pressure the grid sees (Pa; with the closure, `closure.grid_pressure`; with an
    ambient pressure p_a, the gauge pressure p - p_a, `ambient.gauge_pressure`) and compressibility
    kappa = 1 / K (1/Pa)."""
    p = gauge_pressure(layout, params, grid_pressure(layout, params, state))
    return p, 1.0 / bulk_modulus_and_wave_speed(layout, params, state)[0]


def interface_force(
    layout: Layout,
    params: Params,
    stencils: Stencil,
    beta: jax.Array | None,
    state: State,
    sums: NodalSums,
    operators: ddmp.DDMPGrid | None,
    m_min: ArrayLike,
) -> tuple[jax.Array, jax.Array | None, Callable[[jax.Array], jax.Array] | None]:
    """(E13) interface forces between fields from the common pressure (E6), (K, n_nodes, d):
    I_nk = -sum_{p in k} V_p p(x_p) G_np - integral over the cells of field k of theta_k S_n grad p,
    minus the mass-fraction share of the net, so they sum to zero at each node. Returns
    (I, p_amb, volume_rate): the ambient pressure of each field (the common pressure of the
    others, (K, n_nodes)) for the closure (E8) where every field holds one phase (`Layout.
    ambient_by_field`; else `ambient_pressure_by_phase` forms it), or None; with the continuity form
    (E7) the function v (K, n_nodes, d) -> (N,) 1/s of `continuity_volume_rate` at this step, else
    None. With the continuity form I and volume_rate come from one linearisation of the particle
    pressures -> I map (`jax.vjp`), so the map's forward pass (a scatter of the pressures, the
    common pressure, a gather, a scatter and two DDMP contractions) runs once, not twice; the
    phase pressures' moments are scattered inside it, not with the other nodal parts (E15's fit,
    continuity 'off', takes them from g.pressure_moments)."""
    dtype = state.mass.dtype
    if layout.scene.continuity_form == "transport":
        power_density, p_part = _coupling_map(layout, params, stencils, beta, state, sums, operators, m_min)
        I, transpose, mom = jax.vjp(power_density, p_part, has_aux=True)

        def volume_rate(v):
            return fields.safe_div(transpose(v)[0], state.volume, 0.0)
    else:
        mom, volume_rate = sums.pressure_moments, None
        p_n = nodal_common_pressure(layout, params, sums, mom, dtype)
        I = interface_force_of_pressure(layout, stencils, beta, state, sums, operators, m_min, p_n)
    p_amb = None
    if layout.scene.has_closure and layout.ambient_by_field:
        p_amb = fields.ambient_pressure(*_pressure_inputs(layout, sums, mom, dtype))
    return I, p_amb, volume_rate


def ambient_pressure_by_phase(layout: Layout, params: Params, stencils: Stencil, state: State) -> jax.Array:
    """(E8) the closure's ambient pressure at each particle, (N,) Pa: the common pressure (E6) of
    the OTHER phases at the particle's nodes, interpolated; 0 where no other phase is present.
    Formed from one scatter onto a grid per phase of the volume, the compressibility volume and
    the nodal pressure's moments (as the interface forces scatter them per field: E15's fit, or the
    continuity form's averages), so that, at the same estimate of the nodal pressures, it does not
    depend on how the phases are grouped into velocity fields: phases sharing a field are each
    other's ambient as phases in fields of their own are. Needs >= 2 phases."""
    dtype = state.mass.dtype
    p, kappa = phase_pressure_and_compressibility(layout, params, state)
    V = state.volume
    w = stencils.w[..., None]
    sums = scatter_named(
        layout,
        stencils,
        {
            "volume": w * V[:, None, None],
            "compressible_volume": w * (V * kappa)[:, None, None],
            "pressure_moments": pressure_moments(layout, stencils, p, V),
        },
        by_phase=True,
    )
    p_amb = fields.ambient_pressure(
        *_pressure_inputs(layout, sums, sums.pressure_moments, dtype)
    )  # (n_phases, n_nodes)
    return interpolate(stencils, layout.phase, p_amb[..., None])[:, 0]


def pressure_moments(layout: Layout, stencils: Stencil, pressure: jax.Array, volume: jax.Array) -> jax.Array:
    """Per-particle, per-stencil-node moments (N, S, C) from which the nodal phase pressures are
    formed: those of the linear fit (E15), or with the continuity form (E7) w and w p of the
    V_p S_np-weighted average (w = V_p S_np)."""
    if layout.scene.continuity_form == "transport":
        w = volume[:, None] * stencils.w
        return jnp.stack([w, w * pressure[:, None]], -1)
    return fields.lsq_moments(stencils, pressure, volume)


def _pressure_inputs(layout, sums, moments, dtype):
    """Nodal volume fractions, compressibilities and phase pressures, each (K, n_nodes), from the
    scattered parts g and the scattered `pressure_moments` (K, n_nodes, C)."""
    vol = sums.volume[..., 0]
    theta = vol / node_volume(layout, dtype)[None]
    kappa = fields.safe_div(sums.compressible_volume[..., 0], vol, 0.0)
    if layout.scene.continuity_form == "transport":
        w = moments[..., 0]
        return theta, kappa, fields.safe_div(moments[..., 1], w, 1e-12 * jnp.max(w))
    return theta, kappa, fields.lsq_nodal_pressure(moments, layout.dim, layout.scene.grid.h)


def nodal_common_pressure(
    layout: Layout, params: Params, sums: NodalSums, moments: jax.Array, dtype: DTypeLike
) -> jax.Array:
    """(E6) the common pressure p_n (n_nodes,) of the fields in scene.pressure_fields (with an
    ambient pressure p_a, its gauge p_n - p_a: the phase pressures are gauge pressures); with the
    continuity form (E7) its compressive part, max(p_n, 0) of the absolute p_n with a smooth onset
    (`contact_onset`)."""
    theta, kappa, P = _pressure_inputs(layout, sums, moments, dtype)
    w = _shared_weight(layout, dtype)
    shared = theta if w is None else theta * w
    p = fields.common_pressure(shared, kappa, P)
    if layout.scene.continuity_form == "transport":  # fields in contact push, they do not pull (E7)
        p_abs = absolute_pressure(layout, params, p)
        p = gauge_pressure(layout, params, contact_onset(p_abs, onset_pressure(shared, kappa)))
    return p


def onset_pressure(theta: jax.Array, kappa: jax.Array) -> jax.Array:
    """(n_nodes,) the pressure scale of the contact onset (Pa): sqrt(eps) of the nodes' mixture bulk
    modulus sum_k theta_k / sum_k theta_k kappa_k (1.5e-8 of it in float64, 3.5e-4 in float32: 1.1 kPa
    and 27 MPa for aluminium), far above the round-off of a pressure near zero (about eps K) and far
    below the pressures of a contact."""
    K = fields.safe_div(jnp.sum(theta, 0), jnp.sum(theta * kappa, 0), 0.0)
    return jnp.where(K > 0, jnp.sqrt(jnp.finfo(K.dtype).eps) * K, 1.0)  # 1 Pa at empty nodes (p = 0 there)


def contact_onset(p: jax.Array, p_on: jax.Array) -> jax.Array:
    """max(p, 0) with a smooth onset below zero: p r(1 + p / p_on), r(u) = u^2 (3 - 2 u) on
    [0, 1] (0 below, 1 above); p, p_on in Pa, broadcastable arrays (e.g. (n_nodes,)), result
    of p's shape in Pa. It is p for p >= 0 and 0 for p <= -p_on, continuous with its
    derivative (1 at p = 0, as the max's at an exact zero); in the band -p_on < p < 0 it is a
    tension of at most 0.26 p_on.

    Why not max(p, 0) itself: the continuity form's volume rate (E7) is the transpose of the
    interface forces, so it holds the derivative of this map, a step at p = 0 for the max. Where
    two fields share nodes but do not yet press on each other (the sphere and the plate of the
    debris cloud as they meet) p_n is the round-off of a zero pressure, of either sign, and the
    step switched the fields' compressibility share of the closing rate on or off by that sign: a
    change of a few units in the last place of one input grew to 1.9 m/s within 10 steps, a
    0.7 GPa stress jump, and the recomputation of a checkpointed gradient ran another trajectory
    than the forward run. With the onset the same change stays at 1e-11 m/s over 300 steps, and
    the fronts and rear of the debris cloud come out as with the max at zero pressures that are
    exact (tests/test_continuity.py). The map is positively homogeneous of degree one outside the
    band, so the energy identity of `continuity_volume_rate` holds there exactly; in the band the
    interface forces' work and the stored energy differ by at most 0.64 p_on per unit of the rate at
    which the fields close volume at the node."""
    u = jnp.clip(p / p_on + 1.0, 0.0, 1.0)
    return p * (u * u * (3 - 2 * u))


def _shared_weight(layout, dtype):
    """(K, 1) 1 for the fields that share the common pressure, 0 for the others; None when all do.
    Fields outside scene.pressure_fields feel the drag only: no part in p_n, in I or in (E7)."""
    shared = np.isin(np.arange(layout.n_fields), layout.scene.pressure_fields)  # static (K,)
    return None if shared.all() else jnp.asarray(shared, dtype)[:, None]


def interface_force_of_pressure(
    layout: Layout,
    stencils: Stencil,
    beta: jax.Array | None,
    state: State,
    sums: NodalSums,
    operators: ddmp.DDMPGrid | None,
    m_min: ArrayLike,
    p_n: jax.Array,
) -> jax.Array:
    """(E13) the interface forces (K, n_nodes, d) of a nodal common pressure p_n (n_nodes,): linear
    in p_n at the step's geometry (its transpose is the volume rate of the continuity form, E7)."""
    dtype = state.mass.dtype
    w = _shared_weight(layout, dtype)
    grid = layout.scene.grid
    p_p = interpolate(stencils, None, p_n[None, :, None])[:, 0]
    pressure_sums = scatter_named(
        layout, stencils, pressure_parts(stencils, state.volume, beta, p_p, particle_radius(layout, state))
    )
    p_hat = (
        pressure_sums.pressure_share.reshape((layout.n_fields,) + grid.nodes)
        if pressure_sums.pressure_share is not None
        else None
    )
    I = pressure_sums.force + ddmp.nodal_interface_force(grid, operators, p_hat, p_n.reshape(grid.nodes)).reshape(
        pressure_sums.force.shape
    )
    if w is None:
        return fields.share_interface_force(I, sums.mass[..., 0], m_min)
    return fields.share_interface_force(I * w[..., None], sums.mass[..., 0] * w, m_min) * w[..., None]


def continuity_volume_rate(
    layout: Layout,
    params: Params,
    stencils: Stencil,
    beta: jax.Array | None,
    state: State,
    sums: NodalSums,
    operators: ddmp.DDMPGrid | None,
    m_min: ArrayLike,
    v: jax.Array,
) -> jax.Array:
    """(E7, made adjoint to E13) the volume rate (N,) in 1/s that each particle adds to the
    divergence of its own field, so that the work of the interface forces is stored, not created.

    The interface forces I are linear in the common pressure p_m, and p_m (E6 with the V_p S_mp
    averaged phase pressures) is linear in the particle pressures p_p. At the nodal velocities v,
    the interface forces' power is P = v . I = sum_p p_p V_p D_p with

        V_p D_p = dP / dp_p = sum_m R_m (theta_mk kappa_mk / sum_j theta_mj kappa_mj) V_p S_mp / V_mk,
        R_m = dP / dp_m = (B^T v)_m,

    R_m the rate (m^3/s) at which the fields' motion opens (R > 0) or closes (R < 0) volume at node
    m; in the continuum R = sum_k v_k . grad theta_k - v_cm . grad Theta. It takes the place of the
    seed's <div v_i> = (kappa_i / sum_j theta_j kappa_j) Theta div u_m in the same spirit (each
    phase takes its compressibility share of the volume change, and the particles of a phase share
    it by V_p S_mp) but is not that formula: the share is added to each field's own divergence
    instead of replacing it, Theta moves with the mass-averaged velocity v_cm, not the
    volume-averaged u_m, and no nodal pressure is evolved (PHYSICS's pressure = "continuity"
    option); what decides is the energy identity below, which the seed's form broke in impacts.
    Their internal energy then changes by -sum_p p_p V_p D_p dt = -P dt, exactly what the interface
    forces give the motion, and Theta is carried with the mass-averaged velocity,
    d Theta / dt + v_cm . grad Theta = 0: fields that meet are compressed and pushed apart
    instead of passing through each other. D_p is computed as that transpose (jax.vjp of the
    particle pressures -> p_m -> I map at v), so it is adjoint to the discrete forces by
    construction, DDMP and axisymmetric hoop terms included.

    Contact, not cohesion: with this form the common pressure enters I as max(p_m, 0), with a
    smooth onset over p_m in (-p_on, 0) (`contact_onset`, p_on = sqrt(eps) K). Fields in contact
    push each other; when they start to part, their phases expand, p_m falls to zero and the
    coupling lets go, so bodies rebound and separate. The clipped map is homogeneous of degree one
    in the p_p outside the onset band, so the energy identity above holds there exactly. The phase pressures are
    the plain averages here, not the fit (E15): the fit's transpose has large weights of either
    sign at one-sided nodes (a tungsten rod entering steel went non-finite in 1 us with it), the
    average's are positive; with the continuity form the average keeps the settling column at rest."""
    power_density, p_part = _coupling_map(layout, params, stencils, beta, state, sums, operators, m_min)
    _, transpose, _ = jax.vjp(power_density, p_part, has_aux=True)
    return fields.safe_div(transpose(v)[0], state.volume, 0.0)


def _coupling_map(layout, params, stencils, beta, state, sums, operators, m_min):
    """The continuity form's map from the particle pressures (N,) Pa -> the V_p S_mp averaged phase
    pressures' moments (scattered) -> p_m (E6, with the contact onset) -> interface forces (E13)
    (K, n_nodes, d) N, with the moments as an auxiliary output; and the particles' pressures (N,)
    at which the step takes it. Linear in the pressures outside the onset band."""
    dtype = state.mass.dtype

    def power_density(p_part):
        mom = scatter_named(
            layout, stencils, {"pressure_moments": pressure_moments(layout, stencils, p_part, state.volume)}
        ).pressure_moments
        p_n = nodal_common_pressure(layout, params, sums, mom, dtype)
        return interface_force_of_pressure(layout, stencils, beta, state, sums, operators, m_min, p_n), mom

    return power_density, phase_pressure_and_compressibility(layout, params, state)[0]


def exchange_force(
    layout: Layout,
    params: Params,
    m: jax.Array,
    vol: jax.Array,
    v: jax.Array,
    dt: ArrayLike,
    m_min: ArrayLike,
    impulses: bool = False,
) -> jax.Array | tuple[jax.Array, jax.Array]:
    """(E3) implicit exchange force (K, n_nodes, d) at nodal masses m, volumes vol (K, n_nodes)
    and velocities v (K, n_nodes, d), over a time step dt (s).

    The solve runs under lax.cond(dt > 0) (at dt = 0 the step returns its input unchanged, so
    skipping it there changes nothing). The conditional also makes XLA keep the nodal result:
    without it the CPU backend fused the unrolled solve into the particles' gather of the nodal
    acceleration and repeated it for every particle and stencil node. A three-field step of
    benchmarks/multifield_cost.py took 8.5 ms with the conditional, 11.1 ms without (one
    interleaved run, 2-core CPU, float32).

    With scene.window the solve runs on one block of window + 1 nodes per axis placed on the
    nodes where two or more fields have volume: the drag K_kj is proportional to theta_k theta_j
    (E3), so the force is exactly zero at every other node. When those nodes span more than the
    block, the step solves on the whole grid.

    impulses=True: returns (F, J), J (P, n_nodes, d) in N s the momentum each pair of fields
    exchanged (`fields.exchange`; zero where no solve ran)."""
    # longer than 60 lines on purpose: the exchange (E3) of one step: the drag rows, the pairs' solve and the
    # optional heating share its nodal arrays
    scene = layout.scene
    V_n = node_volume(layout, m.dtype)
    n_pairs = m.shape[0] * (m.shape[0] - 1) // 2

    def solve(m, vol, v, V_n):
        theta = vol / V_n[None]
        rho = fields.safe_div(m, vol, 0.0)
        K = fields.drag_rows(
            theta,
            rho,
            v,
            params.drag if scene.drag is not None else None,
            params.drag_length,
            params.linear_drag if scene.linear_drag is not None else None,
        )
        return fields.exchange(m, v, K, dt, V_n, m_min, impulses)

    def zeros(v):
        F = jnp.zeros_like(v)
        return (F, jnp.zeros((n_pairs,) + v.shape[1:], v.dtype)) if impulses else F

    if scene.window is None:
        return jax.lax.cond(dt > 0, lambda: solve(m, vol, v, V_n), lambda: zeros(v))
    nodes = tuple(scene.grid.nodes)
    size = tuple(c + 1 for c in scene.window)
    K, d = m.shape[0], len(nodes)
    shared = (jnp.sum(vol > 0, 0) >= 2).reshape((1,) + nodes).astype(m.dtype)  # nodes where K_kj can be nonzero
    origin, fits = ddmp.window_origin(shared, size)
    origin = jnp.broadcast_to(origin, (K, d))
    on = (dt > 0) & fits[0]

    def take():
        def block(a):
            return ddmp.take_window(a.reshape((a.shape[0],) + nodes + a.shape[2:]), origin, size).reshape(
                (K, -1) + a.shape[2:]
            )

        return block(m), block(vol), block(v), block(V_n[None])[0]

    def nothing():  # no mass: the solve gives zero (its result is not used)
        n = int(np.prod(size))
        return (
            jnp.zeros((K, n), m.dtype),
            jnp.zeros((K, n), m.dtype),
            jnp.zeros((K, n, d), m.dtype),
            jnp.ones((n,), m.dtype),
        )

    F_block = solve(
        *jax.lax.cond(on, take, nothing)
    )  # taken under the conditional: kept as arrays (see ddmp._on_windows)

    def place():
        def put(a):  # F (K, ...) or the pair impulses (P, ...), all on the one block
            at = jnp.broadcast_to(origin[:1], (a.shape[0], d))
            return ddmp.put_window(a.reshape(a.shape[:1] + size + (d,)), at, nodes).reshape(a.shape[:1] + v.shape[1:])

        return tuple(put(a) for a in F_block) if impulses else put(F_block)

    @jax.checkpoint  # differentiated: its residuals are its inputs (see ddmp._on_windows)
    def whole(m, vol, v):
        return jax.lax.cond(dt > 0, lambda: solve(m, vol, v, V_n), lambda: zeros(v))

    return jax.lax.cond(on, place, lambda: whole(m, vol, v))
