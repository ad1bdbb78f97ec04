"""Particle <-> grid transfers: one scatter for all velocity fields, and the gather.

Nodal arrays of all fields are stored flat as (K * n_nodes, C): field k's node n sits at row
k * n_nodes + n (fields as the leading axis once reshaped to (K, n_nodes, C)). Every transfer of
the step goes through the functions here, so a faster formulation changes only this module.
So do the per-particle contractions over the stencil (`stencil_outer`, `stencil_apply`): their
values are sums of broadcast products, not einsums, which XLA's CPU backend turns into slow batched
dot calls for these tiny shapes (benchmarks/throughput.py), and their tangents, under
`jaxmpm.jit`, reductions, which reverse mode transposes to broadcasts instead of a padded copy per
slice (`compile.bilinear_contraction`; tests/test_transfer_forms.py checks both forms, and their
gradients, against the einsums).

Three forms of the transfers:
  scatter / gather                  on a shapes.Stencil, (N, S, C) per particle and stencil node;
                                    used by the musl / seed updates and the multi-field stages.
  scatter_by_offset /               on an OffsetStencil: a loop over the S stencil offsets with the
  gather_by_offset                  per-particle arrays component-major (C, N); the APIC step's
                                    grid-to-particle transfer (gather_by_offset).
  scatter_by_window                 on an OffsetStencil: each particle's width^d block of nodes in
                                    one windowed scatter, the contributions formed for blocks of 8
                                    particles on the minor axis; the APIC step's particle-to-grid
                                    transfer. The APIC step with it against the offset loop, in one
                                    interleaved run (benchmarks/apic_transfer.py): forward 1.9x (3D
                                    48^3) and 1.6x (2D 128^2) faster, gradient 1.4x and 1.3x.
tests/test_transfer_forms.py checks that every form gives the values and gradients of the (N, S, C)
form. A windowed scatter and gather of (N, S, C) rows (particles major, no blocks) measured no
faster for the DDMP steps (one field 1.36x slower, three fields and the debris cloud within 2%).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike, DTypeLike

from jaxmpm.model.geometry import Grid
from jaxmpm.numerics.compile import bilinear_contraction
from jaxmpm.numerics.shapes import TENSOR_SHAPES, Stencil, node_strides, stencil_offsets


def _rows(stencils, field, n_nodes):
    return (
        stencils.node if field is None else stencils.node + (field * int(n_nodes))[:, None].astype(stencils.node.dtype)
    )


def scatter(stencils: Stencil, field: ArrayLike | None, contrib: jax.Array, n_fields: int, n_nodes: int) -> jax.Array:
    """sum over particles of contrib (N, S, C) into nodes: returns (n_fields, n_nodes, C).
    field: (N,) int velocity-field index of each particle, or None when there is one field."""
    n, s, c = contrib.shape
    rows = _rows(stencils, field, n_nodes).reshape(-1)
    out = jnp.zeros((n_fields * n_nodes, c), contrib.dtype).at[rows].add(contrib.reshape(n * s, c))
    return out.reshape(n_fields, n_nodes, c)


def gather(stencils: Stencil, field: ArrayLike | None, nodal: jax.Array) -> jax.Array:
    """Nodal values (K, n_nodes, C) at each particle's stencil nodes in its own field: (N, S, C)."""
    k, n_nodes, c = nodal.shape
    return nodal.reshape(k * n_nodes, c)[_rows(stencils, field, n_nodes)]


def scatter_weighted(
    stencils: Stencil, field: ArrayLike | None, values: jax.Array, n_fields: int, n_nodes: int
) -> jax.Array:
    """sum_p S_np values_p: values (N, C) -> (K, n_nodes, C)."""
    return scatter(stencils, field, stencils.w[..., None] * values[:, None, :], n_fields, n_nodes)


def interpolate(stencils: Stencil, field: ArrayLike | None, nodal: jax.Array) -> jax.Array:
    """sum_n S_np nodal_n: (K, n_nodes, C) -> (N, C)."""
    return jnp.sum(stencils.w[..., None] * gather(stencils, field, nodal), axis=1)


def cell_count(stencils: Stencil, field: ArrayLike | None, n_fields: int, n_cells: int, dtype: DTypeLike) -> jax.Array:
    """(K, n_cells) number of particles of each field in each cell."""
    return cell_sum(stencils, field, n_fields, n_cells, jnp.ones(stencils.cell.shape[0], dtype))


def cell_sum(stencils: Stencil, field: ArrayLike | None, n_fields: int, n_cells: int, values: jax.Array) -> jax.Array:
    """(K, n_cells) sum of a particle quantity (N,) over the particles of each field in each cell."""
    rows = stencils.cell if field is None else stencils.cell + (field * int(n_cells)).astype(stencils.cell.dtype)
    return jnp.zeros(n_fields * n_cells, values.dtype).at[rows].add(values).reshape(n_fields, n_cells)


_outer = bilinear_contraction(
    lambda a, b: sum(a[:, s, :, None] * b[:, s, None, :] for s in range(a.shape[1])),
    lambda a, b: jnp.sum(a[:, :, :, None] * b[:, :, None, :], axis=1),
)
_apply = bilinear_contraction(
    lambda m, b: sum(m[:, None, :, k] * b[:, :, None, k] for k in range(m.shape[-1])),
    lambda m, b: jnp.sum(m[:, None, :, :] * b[:, :, None, :], axis=-1),
)


def stencil_outer(a: jax.Array, b: jax.Array) -> jax.Array:
    """sum_s a_s (x) b_s per particle: a (N, S, A), b (N, S, B) -> (N, A, B), e.g. the velocity
    gradient sum_n v_n (x) grad S_n (1/s for v in m/s, grad S in 1/m). Value unrolled over the S
    stencil nodes (one fused loop); tangent a reduction under jaxmpm.jit
    (`compile.bilinear_contraction`)."""
    return _outer(a, b)


def stencil_apply(m: jax.Array, b: jax.Array) -> jax.Array:
    """m_p . b_ps per particle and stencil node: m (N, A, B), b (N, S, B) -> (N, S, A), e.g. the
    stress force sigma . grad S_n (Pa/m). Value unrolled over the B components; tangent a
    reduction under jaxmpm.jit."""
    return _apply(m, b)


# ------------------------------------------------------------------ transfers offset by offset
@dataclass(frozen=True)
class OffsetStencil:
    """A tensor-product stencil kept as its 1D factors, in component-major layout (particles last),
    for transfers that loop over the width^d stencil offsets (`scatter_by_offset`,
    `gather_by_offset`). Each offset's weights are formed inside the loop from the factors.

    Why: on the CPU, XLA fuses the (N, S, C) contributions of `scatter` with poor vectorisation
    (the minor axes are tiny) and, when the offsets are unrolled, recomputes every per-particle
    input in each offset's fusion. A `fori_loop` over the offsets forms each offset's (C, N) rows
    from inputs computed once, with particles on the minor axis. Measured on the peers' APIC scene
    against the (N, S, C) form in one interleaved run (benchmarks/apic_transfer.py): forward 1.5x
    (2D 128^2) and 1.3x (3D 48^3) faster, gradient 1.7x and 2.3x."""

    w1: jax.Array  # (width, d, N) 1D weights along each axis
    fx: jax.Array  # (d, N) position past the stencil's first node, in cells
    base: jax.Array  # (N,) int32 flat index of the stencil's first node
    offsets: np.ndarray  # (S, d) int32 offsets, first axis slowest (as in `shapes.Stencil`)
    strides: np.ndarray  # (d,) int32 flat-index strides of the nodes
    h: float  # cell size, m
    corner: jax.Array  # (d, N) int32 node multi-index of the stencil's first node
    nodes: tuple  # nodes per axis


def offset_stencil(grid: Grid, x: jax.Array, shape: str = "bspline2") -> OffsetStencil:
    """The OffsetStencil of shape 'bspline2' (quadratic B-spline, 3 nodes per axis) or 'linear'
    (hat, 2 nodes per axis) at positions x (N, d); the same nodes and weights as
    `shapes.bspline2_stencil` / `shapes.linear_stencil`."""
    width, shift, hi_clip, weights_1d = TENSOR_SHAPES[shape]
    d = grid.dim
    xi = ((x - jnp.asarray(grid.origin, x.dtype)) / grid.h).T  # (d, N)
    base = jnp.clip(jnp.floor(xi - shift).astype(jnp.int32), 0, (np.asarray(grid.cells, np.int32) - hi_clip)[:, None])
    fx = xi - base.astype(xi.dtype)
    w1 = jnp.stack(weights_1d(fx))  # (width, d, N)
    strides = node_strides(grid.nodes)
    flat = sum(base[k] * int(strides[k]) for k in range(d))
    return OffsetStencil(
        w1=w1,
        fx=fx,
        base=flat,
        offsets=stencil_offsets(d, width),
        strides=strides,
        h=grid.h,
        corner=base,
        nodes=tuple(grid.nodes),
    )


def _at_offset(offset_stencils, i):
    """Weights S_n(x_p) (N,), x_n - x_p (d, N) in m and node index (N,) of offset i (traced)."""
    o = jnp.asarray(offset_stencils.offsets)[i]
    d = offset_stencils.fx.shape[0]
    w = offset_stencils.w1[o[0], 0]
    for k in range(1, d):
        w = w * offset_stencils.w1[o[k], k]
    dpos = (o.astype(offset_stencils.fx.dtype)[:, None] - offset_stencils.fx) * offset_stencils.h
    node = offset_stencils.base + jnp.sum(o * jnp.asarray(offset_stencils.strides)).astype(offset_stencils.base.dtype)
    return w, dpos, node


def scatter_by_offset(
    offset_stencils: OffsetStencil,
    contrib: Callable[[jax.Array, jax.Array], jax.Array],
    n_channels: int,
    n_nodes: int,
    dtype: DTypeLike,
) -> jax.Array:
    """sum_p over every stencil offset of contrib(w, dpos) (C, N) into nodes: returns (n_nodes, C).
    contrib gets the offset's weights w (N,) and x_n - x_p (d, N); one scatter of C rows per offset."""

    @jax.checkpoint  # reverse mode recomputes the offset's weights instead of storing S copies
    def add(i, out):
        w, dpos, node = _at_offset(offset_stencils, i)
        return out.at[:, node].add(contrib(w, dpos), mode="promise_in_bounds")

    out = jax.lax.fori_loop(
        0, len(offset_stencils.offsets), add, jnp.zeros_like(offset_stencils.fx, dtype, shape=(n_channels, n_nodes))
    )
    return out.T


def gather_by_offset(
    offset_stencils: OffsetStencil,
    nodal: jax.Array,
    accumulate: Callable[[Any, jax.Array, jax.Array, jax.Array], Any],
    init: Any,
) -> Any:
    """Fold the nodal values (C, n_nodes) at every stencil offset into a per-particle carry:
    carry = accumulate(carry, w, dpos, values) with values (C, N) at the offset's nodes."""

    @jax.checkpoint
    def step(i, carry):
        w, dpos, node = _at_offset(offset_stencils, i)
        return accumulate(carry, w, dpos, nodal.at[:, node].get(mode="promise_in_bounds"))

    return jax.lax.fori_loop(0, len(offset_stencils.offsets), step, init)


# ------------------------------------------------------------ the scatter in blocks of particles
WINDOW_BLOCK = 8  # particles per block: one 256-bit vector of float32 (two of float64)


def _block(a, n_blocks, block):
    """(..., N) -> (..., n_blocks, block), zero past N."""
    a = jnp.pad(a, [(0, 0)] * (a.ndim - 1) + [(0, n_blocks * block - a.shape[-1])])
    return a.reshape(a.shape[:-1] + (n_blocks, block))


def _on_axis(a, k, d):
    """(width, n_blocks, block) values along axis k -> (n_blocks, 1.., width at k, ..1, block)."""
    width, nb, block = a.shape
    return jnp.moveaxis(a, 0, 1).reshape((nb,) + (1,) * k + (width,) + (1,) * (d - k - 1) + (block,))


def scatter_by_window(
    offset_stencils: OffsetStencil,
    contrib: Callable[..., list[jax.Array]],
    inputs: Sequence[jax.Array],
    n_channels: int,
    dtype: DTypeLike,
    block: int = WINDOW_BLOCK,
) -> jax.Array:
    """sum_p over each particle's stencil of contrib into nodes: returns (n_nodes, C).

    The particles go in blocks of `block`, particles on the minor axis: contrib(w, dpos, *inputs)
    gets the weights w (n_blocks, width x d, block), x_n - x_p along each axis in m (a tuple of d
    arrays that broadcast against w) and every array of `inputs` (..., N) as (..., n_blocks,
    1 x d, block); it returns the C channels as a list of arrays that broadcast against w. One
    windowed scatter then adds every particle's width^d x C block of nodal values at once (XLA
    computes one start index per particle, and the block's contributions are formed with the
    particles on the vector lanes). Particles past N in the last block have zero weights.

    Why: `scatter_by_offset` forms each offset's rows with the particles minor and XLA then
    transposes them to the scatter's row layout, which took most of its time; rows formed with
    the particles major (the (N, S, C) `scatter`) are poorly vectorised. On the CPU this
    particle-to-grid transfer alone is 3-4x faster in 3D than the offset loop and 2x in 2D."""
    width, d, n = offset_stencils.w1.shape
    nb = -(-n // block)
    w1 = _block(offset_stencils.w1, nb, block)  # (width, d, nb, block)
    fx = _block(offset_stencils.fx, nb, block)  # (d, nb, block)
    w = _on_axis(w1[:, 0], 0, d)
    for k in range(1, d):
        w = w * _on_axis(w1[:, k], k, d)
    o = jnp.arange(width, dtype=fx.dtype)[:, None, None]
    dpos = tuple(_on_axis((o - fx[k]) * offset_stencils.h, k, d) for k in range(d))
    blocked = [_block(a, nb, block).reshape(a.shape[:-1] + (nb,) + (1,) * d + (block,)) for a in inputs]
    parts = contrib(w, dpos, *blocked)
    updates = jnp.stack([jnp.broadcast_to(c, w.shape).astype(dtype) for c in parts], -2)  # (nb, width x d, C, block)
    idx = jnp.moveaxis(_block(offset_stencils.corner, nb, block), 0, -1)  # (nb, block, d)
    dn = jax.lax.ScatterDimensionNumbers(
        update_window_dims=tuple(range(1, d + 2)), inserted_window_dims=(), scatter_dims_to_operand_dims=tuple(range(d))
    )
    out = jax.lax.scatter_add(
        jnp.zeros(offset_stencils.nodes + (n_channels,), dtype),
        idx,
        updates,
        dn,
        mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS,
    )
    return out.reshape(-1, n_channels)
