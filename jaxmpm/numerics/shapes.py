"""Shape functions at the particles: node indices, weights and weight gradients.

Tensor products of 1D functions on the grid (PHYSICS 2.1 stage 1):
  linear hat (2 nodes per axis; standard MPM and the base of DDMP) and
  quadratic B-spline (3 nodes per axis; with APIC/MLS).
The DDMP blend beta (PHYSICS 2.2, the bubble beta = prod_d 4 xi_d (1 - xi_d)) is here too.

Shapes: x (N, d) m; node (N, S) flat node index; w (N, S); dw (N, S, d) 1/m; S = width^d.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.model.geometry import Grid
from jaxmpm.model.scene import Scene


@dataclass(frozen=True)
class Stencil:
    node: jax.Array  # (N, S) int32 flat node index
    w: jax.Array  # (N, S) weight S_n(x_p)
    dw: jax.Array  # (N, S, d) gradient grad S_n(x_p), 1/m
    cell: jax.Array  # (N,) int32 flat index of the cell holding the particle
    xi: jax.Array  # (N, d) position inside that cell (linear) or past the stencil base (bspline2), in cells
    dpos: jax.Array  # (N, S, d) x_n - x_p, m


def node_strides(nodes: Sequence[int]) -> np.ndarray:
    """(d,) int32 flat-index strides of an array of shape `nodes` (C order)."""
    return np.array([int(np.prod(nodes[k + 1 :])) for k in range(len(nodes))], dtype=np.int32)


@jax.custom_jvp
def _product_over_axes(a):
    """prod over the last axis (d <= 3; DDMP's beta): the value one reduction, in the forward step
    and in the gradient's alike. jnp.prod's own derivative rule recomputes the value as products of
    transposed slices, which XLA then fused into every consumer (when the stencil weights were such
    a product too, the elastic impact's scatter contributions took 0.4 ms per step in its gradient
    where the forward step's took 0.05)."""
    return jnp.prod(a, -1)


@_product_over_axes.defjvp
def _product_over_axes_jvp(primals, tangents):
    (a,), (da,) = primals, tangents
    d = a.shape[-1]
    return jnp.prod(a, -1), sum(da[..., k] * _product_of(a, [j for j in range(d) if j != k]) for k in range(d))


def _product_of(a, axes):
    """a[..., j] multiplied over the listed axes j (ones for none)."""
    if not axes:
        return jnp.ones_like(a[..., 0])
    out = a[..., axes[0]]
    for j in axes[1:]:
        out = out * a[..., j]
    return out


def _along_axis(a, k, d):
    """(N, width) -> (N, 1, .., width, .., 1): the width on axis k + 1 of d stencil axes."""
    return a.reshape((a.shape[0],) + tuple(a.shape[1] if e == k else 1 for e in range(d)))


def _product_of_list(arrays):
    """The broadcast product of a list of arrays, left to right."""
    out = arrays[0]
    for a in arrays[1:]:
        out = out * a
    return out


def _tensor(grid, x, width, base_shift, w1d, dw1d, lo_clip, hi_clip):
    d, h = grid.dim, grid.h
    xi = (x - jnp.asarray(grid.origin, x.dtype)) / h
    base = jnp.clip(jnp.floor(xi - base_shift).astype(jnp.int32), lo_clip, np.asarray(grid.cells, np.int32) - hi_clip)
    fx = xi - base.astype(xi.dtype)
    off = stencil_offsets(d, width)  # (S, d)
    n = x.shape[0]
    w1, dw1 = w1d(fx), dw1d(fx) / h  # (N, width, d)
    # the tensor products by broadcasting, axis k of the (N, width, ..., width) block varying with
    # node offset k (C order, as stencil_offsets): their tangents transpose to sums over the other
    # axes, where indexing the 1D weights by the stencil's offsets transposed to scatter-adds
    wk = [_along_axis(w1[:, :, k], k, d) for k in range(d)]
    w = _product_of_list(wk).reshape(n, -1)
    dw = jnp.stack(
        [
            _product_of_list([_along_axis(dw1[:, :, k], k, d) if e == k else wk[e] for e in range(d)]).reshape(n, -1)
            for k in range(d)
        ],
        -1,
    )
    strides = jnp.asarray(node_strides(grid.nodes))
    node = jnp.sum((base[:, None, :] + jnp.asarray(off)[None]) * strides, -1)
    cell_strides = jnp.asarray(node_strides(grid.cells))
    cell = jnp.sum(
        jnp.clip(jnp.floor(xi).astype(jnp.int32), 0, np.asarray(grid.cells, np.int32) - 1) * cell_strides, -1
    )
    dpos = (jnp.asarray(off, x.dtype)[None] - fx[:, None, :]) * h
    return Stencil(node=node, w=w, dw=dw, cell=cell, xi=fx, dpos=dpos)


def linear_weights_1d(f: jax.Array) -> tuple[jax.Array, jax.Array]:
    """1D hat weights of the 2 nodes of an axis at f in [0, 1] past the first: a tuple of arrays
    shaped like f."""
    return (1 - f, f)


def bspline2_weights_1d(f: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """1D quadratic B-spline weights of the 3 nodes of an axis at f in [0.5, 1.5] past the first:
    a tuple of arrays shaped like f."""
    return (0.5 * (1.5 - f) ** 2, 0.75 - (f - 1) ** 2, 0.5 * (f - 0.5) ** 2)


# shape -> (nodes per axis, base shift in cells, upper clip of the base (cells - clip), 1D weights)
TENSOR_SHAPES = {"linear": (2, 0.0, 1, linear_weights_1d), "bspline2": (3, 0.5, 2, bspline2_weights_1d)}


def linear_stencil(grid: Grid, x: jax.Array) -> Stencil:
    """Linear hat S_n(x) = prod_d (1 - |x_d - x_n,d| / h)."""
    w1d = lambda f: jnp.stack(linear_weights_1d(f), 1)
    dw1d = lambda f: jnp.stack([-jnp.ones_like(f), jnp.ones_like(f)], 1)
    return _tensor(grid, x, 2, 0.0, w1d, dw1d, 0, 1)


def bspline2_stencil(grid: Grid, x: jax.Array) -> Stencil:
    """Quadratic B-spline (3 nodes per axis, base = floor(x / h - 1/2))."""
    w1d = lambda f: jnp.stack(bspline2_weights_1d(f), 1)
    dw1d = lambda f: jnp.stack([f - 1.5, -2 * (f - 1), f - 0.5], 1)
    return _tensor(grid, x, 3, 0.5, w1d, dw1d, 0, 2)


def stencil(scene: Scene, x: jax.Array) -> Stencil:
    """The scene's shape functions at x (DDMP uses the linear hat)."""
    return bspline2_stencil(scene.grid, x) if scene.shape == "bspline2" else linear_stencil(scene.grid, x)


def ddmp_beta(xi: jax.Array) -> jax.Array:
    """(E9) blend beta = prod_d 4 xi_d (1 - xi_d): 1 at a cell centre, 0 on cell faces. xi (N, d)."""
    return _product_over_axes(4 * xi * (1 - xi))


def stencil_offsets(dim: int, width: int) -> np.ndarray:
    """(width^dim, dim) integer offsets of a tensor-product stencil, first axis slowest."""
    return np.array(list(itertools.product(range(width), repeat=dim)), dtype=np.int32).reshape(-1, dim)
