"""DDMP node-to-node operators as grid stencils (PHYSICS 2.2, E9-E12 with rules R1-R3).

With the linear hat S_n and the nodal fill theta(x) = sum_n theta_n S_n(x) (R1), on the cells that
hold particles of the field (cell mask, R2):
  V_j          = sum_n theta_n integral(S_j S_n)                       (R3)
  (S_j, grad S_i) = sum_n theta_n integral(S_j S_n grad S_i)
Both are exact integrals of products of hat functions, assembled cell by cell from tensor products
of 1D integrals on the reference cell: A_c[j, i, :] is the contribution of cell c to (S_j, grad S_i)
for its corner nodes j, i. The force (E11) and velocity gradient (E12) use the same A and V, so
they are adjoint (energy-consistent) and exact for linear velocity fields.

Nodal arrays here are dense: (K, *nodes, ...) with K velocity fields; cell arrays (K, *cells, ...).
The per-cell contractions over corners are written as broadcast products and sums, not einsums:
XLA's CPU backend turns these tiny batched contractions into dot calls that took most of a DDMP
step (benchmarks/throughput.py); as sums they fuse into one loop over the cells. Their values are
unrolled sums of slices (the fastest forward); their tangents, which reverse mode transposes, are
reductions when traced for `jaxmpm.jit` (`compile.bilinear_contraction`).
"""

# longer than 400 lines on purpose: one method (DDMP): the cell integrals, the windows of the grid they act on, and
# the nodal forces and velocity gradient built from them, which share the cell tensors

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from jaxmpm.model.geometry import Grid
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import particle_fields
from jaxmpm.numerics.compile import bilinear_contraction
from jaxmpm.numerics.forms import transfer_form
from jaxmpm.numerics.safe import safe_div
from jaxmpm.numerics.shapes import stencil_offsets

# 1D integrals on the unit cell of phi_0 = 1 - s, phi_1 = s.
_P2 = np.array([[1 / 3, 1 / 6], [1 / 6, 1 / 3]])
_P3 = np.array([[[1 / 4, 1 / 12], [1 / 12, 1 / 12]], [[1 / 12, 1 / 12], [1 / 12, 1 / 4]]])
_D3 = _P2[:, :, None] * np.array([-1.0, 1.0])[None, None, :]  # integral phi_a phi_b phi_c'


def _weighted_1d():
    """The 1D integrals of _P2, _P3, _D3 with an extra factor s (the radius weight r = r_c + h s of
    an axisymmetric cell), by 4-point Gauss quadrature (exact for these polynomials)."""
    points, w = np.polynomial.legendre.leggauss(4)
    s, w = 0.5 * (points + 1), 0.5 * w
    phi = np.stack([1 - s, s])
    dphi = np.array([-1.0, 1.0])[:, None] * np.ones_like(s)
    P2 = np.einsum("aq,bq,q->ab", phi, phi, w * s)
    P3 = np.einsum("aq,bq,cq,q->abc", phi, phi, phi, w * s)
    D3 = np.einsum("aq,bq,cq,q->abc", phi, phi, dphi, w * s)
    return P2, P3, D3


@functools.lru_cache(maxsize=8)
def cell_tensors(dim: int, h: float, radius_weight: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """T0[j, n] = integral over a cell of S_j S_n (m^d);
    Tg[j, n, i, k] = integral of S_j S_n dS_i/dx_k (m^(d-1)); j, n, i corner indices (2^d).
    radius_weight: the same integrals with the factor s = (r - r_c) / h along axis 0 (the
    axisymmetric weight r = r_c + h s is then r_c T + h T_s)."""
    off = stencil_offsets(dim, 2)
    s = len(off)
    T0 = np.ones((s, s))
    Tg = np.ones((s, s, s, dim))
    P2w, P3w, D3w = _weighted_1d() if radius_weight else (_P2, _P3, _D3)
    for e in range(dim):
        a = off[:, e]
        P2, P3, D3 = (P2w, P3w, D3w) if e == 0 else (_P2, _P3, _D3)
        T0 *= P2[a[:, None], a[None, :]]
        p3 = P3[a[:, None, None], a[None, :, None], a[None, None, :]]
        d3 = D3[a[:, None, None], a[None, :, None], a[None, None, :]]
        for k in range(dim):
            Tg[..., k] *= d3 if k == e else p3
    return T0 * h**dim, Tg * h ** (dim - 1)


def corners(a: jax.Array, dim: int) -> jax.Array:
    """Nodal (K, *nodes, ...) -> per-cell corner values (K, *cells, 2^d, ...)."""
    out = []
    for o in stencil_offsets(dim, 2):
        idx = (slice(None),) + tuple(slice(int(o[k]), a.shape[1 + k] - 1 + int(o[k])) for k in range(dim))
        out.append(a[idx])
    return jnp.stack(out, axis=1 + dim)


def add_corners(c: jax.Array, dim: int) -> jax.Array:
    """Per-cell corner values (K, *cells, 2^d, ...) summed onto nodes (K, *nodes, ...), in c's
    units. The CPU form (`forms.transfer_form`) loops over the corners (`_add_corners_by_slab`);
    the GPU form is one fused sum of the 2^d padded copies, kept as one array (an optimisation
    barrier) so that XLA does not fuse it into, and repeat it in, each consumer; a loop there
    launches kernels per corner. Both have the same derivatives (the padded sum's)."""
    if transfer_form() == "gpu":
        return jax.lax.optimization_barrier(_add_corners_padded(c, dim))
    return _add_corners_by_slab(c, dim)


@functools.partial(jax.custom_jvp, nondiff_argnums=(1,))
def _add_corners_by_slab(c, dim):
    """add_corners: for each of the 2^d corners, the cells' slab added to the nodes' slab shifted
    by that corner, in a loop over the corners. The loop keeps the sum out of its consumers: fused into the particles' gather, an
    unrolled sum of shifted copies had every cell's contraction recomputed once per particle and
    stencil node (a DDMP step 2-3x slower on the CPU). Slab adds, unlike the scatter-add that did
    this before, run vectorised over the cells: a DDMP step 13-15% faster (measured on the peers'
    2D scene with DDMP, interleaved runs).

    Its tangent is the same sum written as padded copies (`_add_corners_padded`), whose transpose,
    what reverse mode evaluates, is `corners` of the cotangent: slices. The loop's own transpose
    carried the whole cotangent of c through the loop and added each corner's slab into it."""
    return _add_corners_loop(c, dim)


@_add_corners_by_slab.defjvp
def _add_corners_jvp(dim, primals, tangents):
    (c,), (dc,) = primals, tangents
    # the value through the loop itself, so that a derivative of this rule meets it again; the
    # barrier, transposed to one on the cotangent, keeps that cotangent an array for the slices
    return _add_corners_by_slab(c, dim), jax.lax.optimization_barrier(_add_corners_padded(dc, dim))


def _add_corners_loop(c, dim):
    K, cells = c.shape[0], c.shape[1 : 1 + dim]
    extra = tuple(c.shape[2 + dim :])
    nodes = tuple(n + 1 for n in cells)
    offsets = jnp.asarray(stencil_offsets(dim, 2))

    def add(j, out):
        zero = jnp.zeros((), jnp.int32)
        start = (zero,) + tuple(offsets[j, k] for k in range(dim)) + (zero,) * len(extra)
        slab = jax.lax.dynamic_slice(out, start, (K,) + tuple(cells) + extra)
        return jax.lax.dynamic_update_slice(
            out, slab + jax.lax.dynamic_index_in_dim(c, j, 1 + dim, keepdims=False), start
        )

    return jax.lax.fori_loop(
        0, 2**dim, add, jnp.zeros_like(c, shape=(K,) + nodes + extra)
    )  # like c: its device variance too


def _add_corners_padded(c, dim):
    """add_corners as a sum of 2^d copies of the corners' values, each padded by its corner's
    offset: c (K, *cells, 2^d, ...) -> (K, *nodes, ...), in c's units; linear in c, and transposed
    by JAX into the slices of `corners`."""
    n_extra = c.ndim - 2 - dim
    pieces = jax.lax.split(c, (1,) * 2**dim, axis=1 + dim)  # transposed: one concatenate
    out = 0
    for piece, o in zip(pieces, stencil_offsets(dim, 2)):
        widths = ((0, 0),) + tuple((int(o[k]), 1 - int(o[k])) for k in range(dim)) + ((0, 0),) * n_extra
        out = out + jnp.pad(jnp.squeeze(piece, 1 + dim), widths)
    return out


def node_support(grid: Grid, axisymmetric: bool = False) -> np.ndarray:
    """(R1) support volume of each node inside the domain, (*nodes,) m^d: h per axis, h/2 at grid
    edges; axisymmetric: along r the integral of S_n r dr (h r_n inside, h r_n / 2 +- h^2 / 6 at
    the edges), so the volume is per radian like the particles'."""
    vol = np.ones(grid.nodes)
    for k, n in enumerate(grid.nodes):
        f = np.full(n, grid.h)
        f[0] = f[-1] = grid.h / 2
        if axisymmetric and k == 0:
            h = grid.h
            r = grid.origin[0] + h * np.arange(n)
            f = np.where(np.arange(n) > 0, h * r / 2 - h**2 / 6, 0.0) + np.where(
                np.arange(n) < n - 1, h * r / 2 + h**2 / 6, 0.0
            )
        shape = [1] * grid.dim
        shape[k] = n
        vol = vol * f.reshape(shape)
    return vol


@dataclass(frozen=True)
class Window:
    """Where each field's DDMP operators are computed when the scene sets `window`: a block of
    `size` cells (static, the same for every field) placed, per field and per step, at the field's
    first occupied cell. Outside the block a field has no particles, so its cells have no weight
    (R2) and its operators are zero there: computing them on the block gives the whole grid's
    values (round-off equal). When some field's particles span more than the block, `fits` is
    False and the operators are computed on the whole grid instead (`lax.cond`)."""

    size: tuple  # cells per axis of every field's block (static)
    nodes: tuple  # the grid's nodes per axis (static)
    origin: jax.Array  # (K, d) int32: the first cell of each field's block
    fits: jax.Array  # () bool: every field's occupied cells lie in its block
    dense: tuple  # (nodal_volume (K, *nodes), cell_volume (K, *cells)): build's inputs, for the fallback
    axisymmetric: bool


@dataclass(frozen=True)
class DDMPGrid:
    V: jax.Array  # (K, *nodes) V_j of (R3), m^d; on the blocks' nodes (K, *(size + 1)) with a window
    A: jax.Array  # (K, *cells, 2^d, 2^d, d) per-cell (S_j, grad S_i), m^(d-1); the blocks' cells with a window
    theta: jax.Array  # (K, *nodes) nodal fill of (R1); the blocks' nodes with a window
    window: Window | None = None


def window_origin(cell_volume: jax.Array, size: tuple[int, ...]) -> tuple[jax.Array, jax.Array]:
    """Each field's block of `size` cells (static tuple): (K, d) int32 its first cell, at the
    field's first occupied cell (cell_volume (K, *cells) > 0) where the grid allows, and (K,) bool
    whether it holds all the field's occupied cells (True for an empty field)."""
    K, cells = cell_volume.shape[0], cell_volume.shape[1:]
    d = len(cells)
    occupied = cell_volume > jnp.zeros((), cell_volume.dtype)  # a zero of its own dtype: a bool mask too
    origin, fits = [], jnp.ones((K,), bool)
    for e in range(d):
        occ = jnp.any(occupied, axis=tuple(1 + k for k in range(d) if k != e))  # (K, cells_e)
        lo = jnp.argmax(occ, axis=-1)
        hi = cells[e] - 1 - jnp.argmax(occ[:, ::-1], axis=-1)
        o = jnp.clip(lo, 0, cells[e] - size[e])
        origin.append(o)
        fits = fits & ((hi < o + size[e]) | ~jnp.any(occ, axis=-1))
    return jnp.stack(origin, -1).astype(jnp.int32), fits


def fitting_window(scene: Scene, x: ArrayLike, margin: int = 2) -> tuple[int, ...]:
    """A `Scene.window` for positions x (N, d) m (an initial state's): the cells per axis of
    the largest extent of any one field's particles plus `margin` cells on each side, at most the
    grid's cells. Pick the margin from how far the fields will spread; a field that outgrows the
    window costs that step the whole grid, never accuracy."""
    grid = scene.grid
    x = np.asarray(x)
    cell = np.floor((x - np.asarray(grid.origin)) / grid.h).astype(int)
    field = particle_fields(scene)
    extent = np.zeros(grid.dim, int)
    for k in np.unique(field):
        c = cell[field == k]
        extent = np.maximum(extent, c.max(0) - c.min(0) + 1)
    return tuple(int(min(e + 2 * margin, n)) for e, n in zip(extent, grid.cells))


def _index(origin, n_extra):
    return tuple(origin) + (jnp.zeros((), origin.dtype),) * n_extra


def take_window(a: jax.Array, origin: jax.Array, size: tuple[int, ...]) -> jax.Array:
    """a (K or 1, *space, ...) -> (K, *size, ...): each field's block of `size` (static) at its
    origin (K, d); an array of one field (the common pressure) is taken at every field's block."""
    d = len(size)
    extra = tuple(a.shape[1 + d :])
    if a.shape[0] == 1 and origin.shape[0] > 1:
        return jax.vmap(lambda o: jax.lax.dynamic_slice(a[0], _index(o, len(extra)), tuple(size) + extra))(origin)
    return jax.vmap(lambda ak, o: jax.lax.dynamic_slice(ak, _index(o, len(extra)), tuple(size) + extra))(a, origin)


def put_window(w: jax.Array, origin: jax.Array, space: tuple[int, ...]) -> jax.Array:
    """The blocks w (K, *size, ...) placed at their origins (K, d) in zeros (K, *space, ...)."""
    d = len(space)
    extra = tuple(w.shape[1 + d :])
    zeros = jnp.zeros(tuple(space) + extra, w.dtype)
    return jax.vmap(lambda wk, o: jax.lax.dynamic_update_slice(zeros, wk, _index(o, len(extra))))(w, origin)


def _on_windows(grid, operators, op, *nodal):
    """op(operators, *nodal) -> (K, *nodes, ...) for nodal arrays (K or 1, *nodes, ...). With a window: on
    each field's block, placed back on the grid, or on the whole grid when a field outgrows its
    block. Two choices, both measured on benchmarks/multifield_cost.py:
    - the blocks are taken, and the result placed, under the conditional on `fits`, so that XLA's
      CPU backend keeps them as arrays. Fused into their consumers, the dynamic offsets made the
      contractions' cell loops 2-3x slower per cell than the whole grid's, and the placement was
      recomputed for every particle and stencil node of the gathers;
    - the whole-grid branch is rematerialised (jax.checkpoint): a differentiated conditional keeps
      the residuals of both branches, so the whole grid's (zeros, when the blocks are taken) were
      filled every step, 0.3 ms of a 3-field step."""
    w = operators.window
    if w is None:
        return op(operators, *nodal)
    wnodes = tuple(c + 1 for c in w.size)
    K = w.origin.shape[0]
    blocks = jax.lax.cond(
        w.fits,
        lambda: tuple(take_window(a, w.origin, wnodes) for a in nodal),
        lambda: tuple(jnp.zeros((K,) + wnodes + a.shape[1 + len(wnodes) :], a.dtype) for a in nodal),
    )
    on_blocks = op(operators, *blocks)

    @jax.checkpoint  # differentiated, a conditional keeps both branches' residuals: these are the inputs alone
    def on_grid(dense, nodal):
        return op(build(grid, *dense, w.axisymmetric), *nodal)

    return jax.lax.cond(w.fits, lambda: put_window(on_blocks, w.origin, w.nodes), lambda: on_grid(w.dense, nodal))


FILL_RAMP = 0.25


def cell_weight(expected: jax.Array, cell_volume: jax.Array) -> jax.Array:
    """(R2) weight of each cell in the DDMP integrals: 1 where the field's particles hold at least
    FILL_RAMP of the volume `expected` that the nodal fill theta puts in the cell, falling linearly
    to 0 with no particle. A cell that holds only a trace of material (a dust of 1e-12 of its
    neighbours' mass) then takes almost no stress from its neighbours' nodes, which would otherwise
    accelerate its nodes without bound (the binary rule counted any particle as a full cell: a block
    beside such dust reached 1e11 m/s in one step); the force on a trace node is at most
    1 / FILL_RAMP times the one its own material gives it. Cells holding a fair share of material
    count fully, as before, and any nonnegative weights keep E11/E12 adjoint and exact for linear
    fields. expected, cell_volume: (K, *cells) m^d (per radian if axisymmetric)."""
    return jnp.clip(safe_div(cell_volume, FILL_RAMP * expected, 0.0), 0.0, 1.0) * (cell_volume > 0).astype(
        cell_volume.dtype
    )


def _cell_integrator(grid, dtype, axisymmetric, r_c=None):
    """integrate(tc, T, T_s): the cell integrals of theta-weighted products, sum_n tc_n T[j, n, ...]
    (K, *cells, 2^d, ...), with the axisymmetric weight r = r_c + h s along axis 0 (r_c T + h T_s)."""
    d = grid.dim

    def plain(tc, T):
        # sum_n tc_n T[j, n, ...] as one (cells, n) @ (n, j ...) product: a library matmul, which
        # XLA computes once instead of fusing it into (and repeating it in) every consumer
        Tm = jnp.asarray(np.moveaxis(T, 1, 0).reshape(T.shape[1], -1), dtype)
        out = tc.reshape(-1, tc.shape[-1]) @ Tm
        return out.reshape(tc.shape[:-1] + T.shape[:1] + T.shape[2:])

    if not axisymmetric:
        return lambda tc, T, Ts: plain(tc, T)
    if r_c is None:  # (1 or K, cells_0, 1, ...): the radius of each cell's first node
        r_c = jnp.asarray(grid.origin[0] + grid.h * np.arange(grid.cells[0]), dtype).reshape((1, -1) + (1,) * (d - 1))

    def integrate(tc, T, Ts):
        # r_c (tc T) + h (tc Ts) as one product [r_c tc, h tc] @ [T; Ts]: reverse mode then sums the
        # cotangents of the integrals (one per use of A, V) once, where the two products' transposes
        # each summed them (the debris cloud's gradient summed eleven (K, cells, 32) arrays twice)
        rc = jnp.broadcast_to(r_c[..., None], tc.shape)
        return plain(jnp.concatenate([rc * tc, grid.h * tc], -1), np.concatenate([T, Ts], 1))

    return integrate


def build(
    grid: Grid,
    nodal_volume: jax.Array,
    cell_volume: jax.Array,
    axisymmetric: bool = False,
    window: tuple[int, ...] | None = None,
) -> DDMPGrid:
    """Assemble V and A from the nodal particle volume (K, *nodes) = sum_p V_p S_n(x_p) and the
    particle volume in each cell (K, *cells); axisymmetric: integrals weighted by the radius r
    (volumes per radian). window: None (the whole grid) or the cells per axis of each field's
    block (`Window`), a static tuple of d ints <= grid.cells."""
    d = grid.dim
    T0, Tg = cell_tensors(d, grid.h)
    T0s, Tgs = cell_tensors(d, grid.h, True) if axisymmetric else (None, None)
    dtype = nodal_volume.dtype
    support = jnp.asarray(node_support(grid, axisymmetric), dtype)[None]
    win, r_c = None, None
    if window is not None:
        window = tuple(int(c) for c in window)
        origin, fits = window_origin(cell_volume, window)
        win = Window(
            size=window,
            nodes=tuple(grid.nodes),
            origin=origin,
            fits=jnp.all(fits),
            dense=(nodal_volume, cell_volume),
            axisymmetric=axisymmetric,
        )
        wnodes = tuple(w + 1 for w in window)
        nodal_volume = take_window(nodal_volume, origin, wnodes)
        cell_volume = take_window(cell_volume, origin, window)
        support = take_window(jnp.broadcast_to(support, nodal_volume.shape[:1] + support.shape[1:]), origin, wnodes)
        if axisymmetric:
            r_all = jnp.asarray(grid.origin[0] + grid.h * np.arange(grid.cells[0]), dtype)
            r_c = jax.vmap(lambda o: jax.lax.dynamic_slice(r_all, (o,), (window[0],)))(origin[:, 0])
            r_c = r_c.reshape(r_c.shape + (1,) * (d - 1))
    integrate = _cell_integrator(grid, dtype, axisymmetric, r_c)
    theta = jnp.clip(nodal_volume / support, 0.0, 1.0)  # (R1)
    tc = corners(theta, d)
    expected = jnp.sum(integrate(tc, T0, T0s), axis=-1)  # integral of theta over the cell
    tc = tc * cell_weight(expected, cell_volume)[..., None]  # (R2)
    Vc = integrate(tc, T0, T0s)
    A = integrate(tc, Tg, Tgs)
    V = add_corners(Vc, d)  # (R3)
    return DDMPGrid(V=V, A=A, theta=theta, window=win)


# sum_{j,b} s_jab A_jib -> (..., i, a): the stress force (E11)
_force_contraction = bilinear_contraction(
    lambda s, A: sum(
        s[..., j, None, :, b] * A[..., j, :, None, b] for j in range(A.shape[-3]) for b in range(A.shape[-1])
    ),
    lambda s, A: jnp.sum(s[..., :, None, :, :] * A[..., :, :, None, :], axis=(-4, -1)),
)
# sum_i v_ia A_jib -> (..., j, a, b): the velocity gradient (E12)
_gradient_contraction = bilinear_contraction(
    lambda v, A: sum(v[..., None, i, :, None] * A[..., :, i, None, :] for i in range(A.shape[-2])),
    lambda v, A: jnp.sum(v[..., None, :, :, None] * A[..., :, :, None, :], axis=-3),
)
# sum_j q_j A_jik -> (..., i, k): the stress force (E11) of an isotropic share q I
_isotropic_contraction = bilinear_contraction(
    lambda q, A: sum(q[..., j, None, None] * A[..., j, :, :] for j in range(A.shape[-3])),
    lambda q, A: jnp.sum(q[..., :, None, None] * A, axis=-3),
)
# sum_i p_i A_nik -> (..., n, k): the integral of theta S_n grad p
_scalar_contraction = bilinear_contraction(
    lambda p, A: sum(p[..., None, i, None] * A[..., :, i, :] for i in range(A.shape[-2])),
    lambda p, A: jnp.sum(p[..., None, :, None] * A, axis=-2),
)


def nodal_stress_force(grid: Grid, operators: DDMPGrid, sigma_hat_volume: jax.Array) -> jax.Array:
    """(E11) second part: f_i = - sum_j sigma_hat_j . (S_j, grad S_i).
    sigma_hat_volume: (K, *nodes, d, d) = sum_p V_p (1 - beta_p) sigma_p S_j(x_p) (Pa m^d).
    Returns (K, *nodes, d) in N."""
    d = grid.dim
    vmin = 1e-12 * grid.h**d

    def op(operators, shv):
        sc = corners(safe_div(shv, operators.V[..., None, None], vmin), d)  # (..., j, a, b)
        return add_corners(-_force_contraction(sc, operators.A), d)

    return _on_windows(grid, operators, op, sigma_hat_volume)


def nodal_interface_force(grid: Grid, operators: DDMPGrid, p_hat_volume: jax.Array | None, p: jax.Array) -> jax.Array:
    """The DDMP part of the interface forces (E13), in one pass over the cells:
    f_n = - sum_j p_hat_j (S_j, grad S_n) - sum_i p_i (S_n, grad S_i).
    The first term is the stress force (E11, second part) of an isotropic nodal share p_hat I, from
    p_hat_volume (K, *nodes) = sum_p V_p (1 - beta_p) p_p S_j(x_p) (Pa m^d) alone (one product per
    corner and component where the tensor's contraction takes d); None: no such term. The second is
    the integral over each field's cells of theta S_n grad p for the common pressure p (*nodes,),
    Pa, shared by all fields. Returns (K, *nodes, d) in N."""
    d = grid.dim
    vmin = 1e-12 * grid.h**d

    def op(operators, p, *p_hat_volume):
        c = -_scalar_contraction(corners(p, d), operators.A)
        for phv in p_hat_volume:
            c = c - _isotropic_contraction(corners(safe_div(phv, operators.V, vmin), d), operators.A)
        return add_corners(c, d)

    return _on_windows(grid, operators, op, p[None], *(() if p_hat_volume is None else (p_hat_volume,)))


def nodal_velocity_gradient(grid: Grid, operators: DDMPGrid, v: jax.Array) -> jax.Array:
    """(E12) L-bar_j = (1 / V_j) sum_i v_i (x) (S_j, grad S_i). v: (K, *nodes, d) -> (K, *nodes, d, d)."""
    d = grid.dim
    vmin = 1e-12 * grid.h**d

    def op(operators, v):
        vc = corners(v, d)  # (..., i, a)
        return safe_div(add_corners(_gradient_contraction(vc, operators.A), d), operators.V[..., None, None], vmin)

    return _on_windows(grid, operators, op, v)
