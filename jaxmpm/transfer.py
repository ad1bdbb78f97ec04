"""Particle <-> grid transfers: one scatter for all velocity fields, and the gather.

Nodal arrays of all fields are stored flat as (K * n_nodes, C): field k's node n sits at row
k * n_nodes + n (fields as the leading axis once reshaped to (K, n_nodes, C)). Every transfer of
the step goes through these two functions, so a faster formulation changes only this module.
So do the per-particle contractions over the stencil (`stencil_outer`, `stencil_apply`): written
as sums of broadcast products, not einsums, which XLA's CPU backend turns into slow batched dot
calls for these tiny shapes (benchmarks/throughput.py; tests/test_transfer_forms.py checks them,
and their gradients, against the einsums).
"""
from __future__ import annotations

import jax.numpy as jnp


def _rows(st, field, n_nodes):
    return st.node if field is None else st.node + (field * n_nodes)[:, None]


def scatter(st, field, contrib, n_fields, n_nodes):
    """sum over particles of contrib (N, S, C) into nodes: returns (n_fields, n_nodes, C).
    field: (N,) int velocity-field index of each particle, or None when there is one field."""
    n, s, c = contrib.shape
    rows = _rows(st, field, n_nodes).reshape(-1)
    out = jnp.zeros((n_fields * n_nodes, c), contrib.dtype).at[rows].add(contrib.reshape(n * s, c))
    return out.reshape(n_fields, n_nodes, c)


def gather(st, field, nodal):
    """Nodal values (K, n_nodes, C) at each particle's stencil nodes in its own field: (N, S, C)."""
    k, n_nodes, c = nodal.shape
    return nodal.reshape(k * n_nodes, c)[_rows(st, field, n_nodes)]


def scatter_weighted(st, field, values, n_fields, n_nodes):
    """sum_p S_np values_p: values (N, C) -> (K, n_nodes, C)."""
    return scatter(st, field, st.w[..., None] * values[:, None, :], n_fields, n_nodes)


def interpolate(st, field, nodal):
    """sum_n S_np nodal_n: (K, n_nodes, C) -> (N, C)."""
    return jnp.sum(st.w[..., None] * gather(st, field, nodal), axis=1)


def cell_count(st, field, n_fields, n_cells, dtype):
    """(K, n_cells) number of particles of each field in each cell."""
    return cell_sum(st, field, n_fields, n_cells, jnp.ones(st.cell.shape[0], dtype))


def cell_sum(st, field, n_fields, n_cells, values):
    """(K, n_cells) sum of a particle quantity (N,) over the particles of each field in each cell."""
    rows = st.cell if field is None else st.cell + field * n_cells
    return jnp.zeros(n_fields * n_cells, values.dtype).at[rows].add(values).reshape(n_fields, n_cells)


def stencil_outer(a, b):
    """sum_s a_s (x) b_s per particle: a (N, S, A), b (N, S, B) -> (N, A, B), e.g. the velocity
    gradient sum_n v_n (x) grad S_n. Unrolled over the S stencil nodes (one fused loop)."""
    return sum(a[:, s, :, None] * b[:, s, None, :] for s in range(a.shape[1]))


def stencil_apply(m, b):
    """m_p . b_ps per particle and stencil node: m (N, A, B), b (N, S, B) -> (N, S, A), e.g. the
    stress force sigma . grad S_n. Unrolled over the B components."""
    return sum(m[:, None, :, k] * b[:, :, None, k] for k in range(m.shape[-1]))
