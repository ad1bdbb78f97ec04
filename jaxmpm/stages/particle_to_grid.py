"""Stage 2 of the step (PHYSICS 2.1): particle to grid. One scatter of what the grid stage needs
(mass, momentum, stress force, and the nodal volume, compressibility and pressure moments where
DDMP or interface forces need them), as a `NodalSums`; and the particles' body acceleration
(gravity, ramped, and the phases' body forces).

Shapes: N particles, S stencil nodes, K velocity fields, n nodes, d dimensions; `layout` is a
jaxmpm.stages.layout.Layout, `stencils` the step's stencil (stage 1). SI units.
"""

from __future__ import annotations

import jax

from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.numerics.shapes import Stencil
from jaxmpm.stages.layout import Layout

import jax.numpy as jnp

from jaxmpm.stages.ambient import gauge_stress
from jaxmpm.stages.closure import force_stress
from jaxmpm.stages.multifield import phase_pressure_and_compressibility, pressure_moments
from jaxmpm.stages.nodal import NodalSums, particle_radius, scatter_named, stress_parts


def gravity_now(params: Params, t: jax.Array) -> jax.Array:
    """Gravity (d,) at time t, ramped smoothly over params.gravity_ramp: g (1 - cos(pi t / T)) / 2."""
    T = params.gravity_ramp
    on = T > 0
    r = 0.5 * (1 - jnp.cos(jnp.pi * jnp.clip(t / jnp.where(on, T, 1.0), 0.0, 1.0)))
    return params.gravity * jnp.where(on, r, 1.0)


def body_acceleration(layout: Layout, params: Params, state: State) -> jax.Array | None:
    """(N, d) per-particle body acceleration from gravity and per-phase body forces (m/s^2), or None."""
    scene = layout.scene
    acc = None
    if scene.gravity is not None:
        acc = jnp.broadcast_to(gravity_now(params, state.t), state.v.shape)
    if scene.body_force:
        b = jnp.concatenate(
            [
                jnp.broadcast_to(params.body_force[p.name], (sl.stop - sl.start, layout.dim))
                for p, sl in zip(scene.phases, layout.slices)
            ]
        )
        acc = b if acc is None else acc + b
    return acc


def particle_to_grid(
    layout: Layout, params: Params, stencils: Stencil, state: State, beta: jax.Array | None
) -> NodalSums:
    """Stage 2: one scatter of mass, momentum and stress force for all fields, plus what DDMP
    (nodal volume, stress share) and the multi-field stage (compressibility; E15's fit moments,
    which the continuity form scatters in `multifield.interface_force` instead) need.
    Returns the `NodalSums` (K, n_nodes, C)."""
    m, v, V = state.mass, state.v, state.volume
    w = stencils.w[..., None]
    parts = {"mass": w * m[:, None, None], "momentum": w * (m[:, None] * v)[:, None, :]}
    sig = gauge_stress(layout, params, force_stress(layout, params, state))
    parts.update(stress_parts(stencils, V, beta, sig, particle_radius(layout, state)))
    if beta is not None or layout.n_fields > 1:
        parts["volume"] = w * V[:, None, None]
    if layout.scene.has_interface_forces:
        p, kappa = phase_pressure_and_compressibility(layout, params, state)
        if layout.scene.continuity_form != "transport":
            parts["pressure_moments"] = pressure_moments(layout, stencils, p, V)  # (E15)
        parts["compressible_volume"] = w * (V * kappa)[:, None, None]
    return scatter_named(layout, stencils, parts)
