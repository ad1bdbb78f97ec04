"""The pressure of the surroundings (`Scene.ambient_pressure`, p_a): the grid sees gauge stresses.

    sigma_g = sigma + p_a I     the stress whose divergence the grid takes (E2, E11)
    p_g     = p - p_a           the phase pressures the common pressure (E6) and the interface
                                forces (E13) are formed from

Why this is the same physics: div(p_a I) = 0 inside the material, and at a free surface the
surroundings (the void, at p_a) press on the material with the traction -p_a n, which cancels the
traction p_a n of sigma's uniform part; at a wall the wall takes whatever normal force the
material exerts. So the weak form of div sigma with the void at p_a is that of div sigma_g with a
traction-free surface. Why it matters: the particle quadrature of a uniform stress,
-sum_p V_p sigma . grad S_n(x_p), is zero only where the particles sit evenly in their cells;
moved, it pushes the nodes in proportion to the stress itself, and a gas, whose bulk modulus is of
the order of its absolute pressure (1.4 p for air), has nothing to hold that with: grid modes
whose force from the absolute pressure outweighs the elastic one grow from round-off (air at
1 atm in a box: 1e-9 -> 21 m/s in 2 ms, at a rate 0.25 sqrt(p / rho) / h that does not depend on
the time step; with the gauge stress it stays at rest, docs/limitations.md). With several fields,
E6's weights sum to one, so the common pressure of the gauge pressures is p - p_a, and the
fields' interface forces (E13) keep cancelling each field's own share of a uniform pressure.

The surroundings do work on the material, -p_a dV/dt over its volume V = sum_p V_p: the
conserved energy holds p_a V (`jaxmpm.diagnostics.total_energy`). Without the scene option (None)
nothing here is traced.

Shapes: N particles, d the stress's dimension; SI units.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxmpm.model.params import Params
from jaxmpm.stages.layout import Layout


def gauge_stress(layout: Layout, params: Params, stress: jax.Array) -> jax.Array:
    """(N, d, d) the gauge stress sigma + p_a I the grid sees, Pa; `stress` itself without an
    ambient pressure."""
    if layout.scene.ambient_pressure is None:
        return stress
    d = stress.shape[-1]
    return stress + params.ambient_pressure.astype(stress.dtype) * jnp.eye(d, dtype=stress.dtype)


def gauge_pressure(layout: Layout, params: Params, p: jax.Array) -> jax.Array:
    """(N,) or nodal: the gauge pressure p - p_a, Pa; p itself without an ambient pressure."""
    if layout.scene.ambient_pressure is None:
        return p
    return p - params.ambient_pressure.astype(p.dtype)


def absolute_pressure(layout: Layout, params: Params, p_g: jax.Array) -> jax.Array:
    """The inverse of `gauge_pressure`: p_g + p_a, Pa."""
    if layout.scene.ambient_pressure is None:
        return p_g
    return p_g + params.ambient_pressure.astype(p_g.dtype)
