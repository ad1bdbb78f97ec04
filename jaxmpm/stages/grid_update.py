"""Stage 3 of the step (PHYSICS 2.1): the grid update. From stage 2's `NodalSums`: the nodal
velocity and acceleration of every velocity field, with the internal force (E11), the interface
forces (E13), body forces, damping, walls and the implicit exchange (E3), handed to stage 4 as a
`GridUpdate`. The parts are in jaxmpm.stages.nodal (scatters, DDMP operators, stress force) and
jaxmpm.stages.multifield (the coupling of fields).

Shapes: N particles, K velocity fields, n nodes, d dimensions; SI units.
"""

from __future__ import annotations

from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.numerics.shapes import Stencil
from jaxmpm.stages.layout import Layout
from jaxmpm.stages.nodal import NodalSums

import jax

from jaxmpm.numerics.transfer import scatter
from jaxmpm.stages import fields
from jaxmpm.stages.layout import apply_walls, wall_acceleration
from jaxmpm.stages.multifield import exchange_force, interface_force
from jaxmpm.stages.nodal import GridUpdate, ddmp_operators, nodal_stress_force


def grid_acceleration(
    layout: Layout,
    params: Params,
    state: State,
    stencils: Stencil,
    beta: jax.Array | None,
    sums: NodalSums,
    acc_p: jax.Array | None,
    dt: jax.Array,
    m_min: jax.Array,
) -> GridUpdate:
    """Stage 3: nodal velocity v_old (walls applied) and acceleration a (K, n_nodes, d):
    internal force (E11), interface forces (E13), body forces, damping, implicit exchange (E3).
    Returns a `GridUpdate`: v_old, a, the DDMP operators or None, the closure's ambient pressure
    (K, n_nodes) where every field holds one phase and the fields have interface forces (else None:
    `grid_to_particle` forms it per phase, E8), the continuity form's volume rate v -> (N,)
    (`multifield.interface_force`) or None, the exchange's pair impulses (P, n_nodes, d) in N s
    with scene.drag_heating (`fields.exchange`), else None."""
    scene = layout.scene
    dtype = state.mass.dtype
    operators = None
    if beta is not None or scene.has_interface_forces:
        with jax.named_scope("ddmp_operators"):
            operators = ddmp_operators(layout, stencils, sums.volume[..., 0], dtype, state.volume)
    m = sums.mass
    v = apply_walls(layout, fields.safe_div(sums.momentum, m, m_min))
    with jax.named_scope("stress_force"):
        f = nodal_stress_force(layout, operators, sums)
    p_amb, volume_rate = None, None
    if scene.has_interface_forces:
        with jax.named_scope("interface_force"):
            I, p_amb, volume_rate = interface_force(layout, params, stencils, beta, state, sums, operators, m_min)
        f = f + I
    if acc_p is not None:
        f = f + layout.particle_sum(
            scatter(
                stencils,
                layout.field,
                stencils.w[..., None] * (state.mass[:, None] * acc_p)[:, None, :],
                layout.n_fields,
                layout.n_nodes,
            )
        )
    a = fields.safe_div(f, m, m_min)
    if scene.damping is not None:
        a = a - params.damping * v
    a = wall_acceleration(layout, v, a, dt)
    impulses = None
    if scene.has_exchange:
        with jax.named_scope("exchange"):
            F = exchange_force(
                layout, params, m[..., 0], sums.volume[..., 0], v + dt * a, dt, m_min, scene.drag_heating
            )
            if scene.drag_heating:
                F, impulses = F
        a = wall_acceleration(layout, v, a + fields.safe_div(F, m, m_min), dt)
    return GridUpdate(v, a, operators, p_amb, volume_rate, impulses)
