"""Multi-velocity grid stage: volume fractions, common pressure, interface forces, exchange.

With K velocity fields, nodal arrays carry the fields as a leading axis (K, n_nodes, ...). All of
this is traced only for scenes with K >= 2; a one-field scene never calls into this module.

  theta_nk = V_nk / V_n                                  nodal volume fraction (V_n: node support, R1)
  P_nk     value at node n of the V_p S_np-weighted linear least-squares fit of the particle
           pressures of field k                            (E15)
  p_n      = sum_k f_k P_nk, f_k = theta_k kappa_k / sum_j theta_j kappa_j     (E6)
  I_nk     = -sum_{p in k} V_p p(x_p) G_np - integral_{cells of k} theta_k S_n grad p dV
  f_nk    += I_nk - (m_nk / M_n) sum_j I_nj                                      (E13)
  exchange (E3), implicit per node:
           m_k v_k + dt V_n sum_j K_kj (v_k - v_j) = m_k v*_k,
           K_kj = C_d theta_k theta_j rho_f |v*_k - v*_j| / d + K_lin theta_k theta_j,
           rho_f the true density of the lighter of the two phases.
  heat (scene option drag_heating): the drag's work over the step on each pair of fields,
           J_kj . (v_k - v_j), split between the pair (`drag_heat`), to the particles' internal energy.
Shapes: K fields, n nodes, d dimensions; SI units.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxmpm.numerics.safe import safe_div
from jaxmpm.numerics.shapes import Stencil


def solve_small(A: jax.Array, b: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Solve A x = b for many small systems by Gaussian elimination without pivoting, unrolled
    (A: (..., n, n) symmetric positive definite or diagonally dominant, n <= 4; b: (..., n, k)).
    Returns (x, det A). Batched LAPACK calls are slow for millions of tiny systems on the CPU; this
    is a handful of fused elementwise operations. Singular rows give non-finite x: guard outside."""
    n = A.shape[-1]
    x, det = solve_rows([[A[..., i, j] for j in range(n)] for i in range(n)], [b[..., i, :] for i in range(n)])
    return jnp.stack(x, -2), det


def solve_rows(A: list[list[jax.Array]], b: list[jax.Array]) -> tuple[list[jax.Array], jax.Array]:
    """`solve_small` on a system given as nested lists: A[i][j] arrays of one batch shape (...),
    b[i] arrays (..., k). Returns (x as a list of n arrays (..., k), det A (...)). With the batch
    axis minor (nodes last), every operation is one elementwise loop over contiguous memory."""
    n = len(A)
    rows = [list(r) for r in A]
    rhs = list(b)
    det = jnp.ones_like(rows[0][0])
    for i in range(n):
        piv = rows[i][i]
        det = det * piv
        for j in range(i + 1, n):
            f = rows[j][i] / piv
            rows[j] = [rows[j][c] - f * rows[i][c] for c in range(n)]
            rhs[j] = rhs[j] - f[..., None] * rhs[i]
    x = [None] * n
    for i in reversed(range(n)):
        acc = rhs[i]
        for j in range(i + 1, n):
            acc = acc - rows[i][j][..., None] * x[j]
        x[i] = acc / rows[i][i][..., None]
    return x, det


def lsq_moments(stencils: Stencil, pressure: jax.Array, volume: jax.Array) -> jax.Array:
    """Per-particle, per-stencil-node contributions (N, S, C) for the linear fit (E15):
    w, w r, w r r^T, w p, w p r with w = V_p S_np and r = x_p - x_n. C = 2 + 2 d + d^2."""
    w = (volume[:, None] * stencils.w)[..., None]  # (N, S, 1)
    r = -stencils.dpos  # (N, S, d)
    d = r.shape[-1]
    rr = (r[..., :, None] * r[..., None, :]).reshape(r.shape[:-1] + (d * d,))
    p = pressure[:, None, None]
    return jnp.concatenate([w, w * r, w * rr, w * p, w * p * r], -1)


def lsq_nodal_pressure(moments: jax.Array, d: int, h: float) -> jax.Array:
    """(E15) P_nk = a of the fit p ~ a + b . (x - x_n) from the scattered moments (K, n, C);
    the plain weighted average where the fit is singular (a node seen by particles on a line)."""
    w = moments[..., 0]
    wr = moments[..., 1 : 1 + d]
    wrr = moments[..., 1 + d : 1 + d + d * d].reshape(moments.shape[:-1] + (d, d))
    wp = moments[..., 1 + d + d * d]
    wpr = moments[..., 2 + d + d * d :]
    top = jnp.concatenate([w[..., None], wr], -1)[..., None, :]  # (K, n, 1, d+1)
    rest = jnp.concatenate([wr[..., :, None], wrr], -1)  # (K, n, d, d+1)
    M = jnp.concatenate([top, rest], -2)  # (K, n, d+1, d+1)
    rhs = jnp.concatenate([wp[..., None], wpr], -1)
    # condition: scale the position block by h so the matrix is O(w) throughout
    scale = jnp.concatenate([jnp.ones(1, M.dtype), jnp.full((d,), 1.0 / h, M.dtype)])
    Ms = M * scale[:, None] * scale[None, :]
    wmin = 1e-12 * jnp.max(w)
    eye = jnp.eye(d + 1, dtype=M.dtype)
    safe = jnp.where((w > wmin)[..., None, None], Ms, eye)
    _, det = solve_small(safe, jnp.zeros(safe.shape[:-1] + (1,), M.dtype))
    ok = (w > wmin) & (jnp.abs(det) > 1e-6 * jnp.maximum(w, wmin) ** (d + 1))
    sol = solve_small(jnp.where(ok[..., None, None], Ms, eye), (rhs * scale)[..., None])[0][..., 0]
    average = safe_div(wp, w, wmin)
    return jnp.where(ok, sol[..., 0], average)


def common_pressure(theta: jax.Array, kappa: jax.Array, P: jax.Array) -> jax.Array:
    """(E6) p_n = sum_k theta_k kappa_k P_k / sum_j theta_j kappa_j. theta, kappa, P: (K, n) -> (n,)."""
    tk = theta * kappa
    return safe_div(jnp.sum(tk * P, 0), jnp.sum(tk, 0), 0.0)


def share_interface_force(I: jax.Array, m: jax.Array, m_min: ArrayLike) -> jax.Array:
    """(E13) I_nk - (m_nk / M_n) sum_j I_nj: sums to zero over fields at every node and vanishes
    where one field is alone. I: (K, n, d), m: (K, n)."""
    M = jnp.sum(m, 0)
    share = safe_div(m, M[None], m_min)
    return I - share[..., None] * jnp.sum(I, 0)[None]


def drag_matrix(
    theta: jax.Array, rho: jax.Array, v: jax.Array, cd: ArrayLike | None, length: ArrayLike, k_lin: ArrayLike | None
) -> jax.Array:
    """K_kj of (E3) per node (K, K, n) in kg/(m^3 s), symmetric with a zero diagonal, nodes minor.
    theta: (K, n) volume fractions; rho: (K, n) true densities, kg/m^3; v: (K, n, d) m/s.
    cd (dimensionless, or None: no quadratic term), length (m), k_lin (kg/(m^3 s), or None: no
    linear term)."""
    rows = drag_rows(theta, rho, v, cd, length, k_lin)
    return jnp.stack([jnp.stack([jnp.zeros_like(theta[0]) if K_kj is None else K_kj for K_kj in r]) for r in rows])


def drag_rows(
    theta: jax.Array, rho: jax.Array, v: jax.Array, cd: ArrayLike | None, length: ArrayLike, k_lin: ArrayLike | None
) -> list[list[jax.Array | None]]:
    """`drag_matrix` as nested lists: rows[k][j] the (n,) coefficient K_kj in kg/(m^3 s), None on
    the diagonal.
    Each of the K (K - 1) / 2 pairs is formed once, component by component, elementwise over the
    nodes."""
    n_f, d = theta.shape[0], v.shape[-1]
    rows = [[None] * n_f for _ in range(n_f)]
    for k in range(n_f):
        for j in range(k + 1, n_f):
            tt = theta[k] * theta[j]
            K_kj = jnp.zeros_like(tt)
            if cd is not None:
                s2 = sum((v[k, :, c] - v[j, :, c]) ** 2 for c in range(d))
                speed = jnp.where(s2 > 0, jnp.sqrt(jnp.where(s2 > 0, s2, 1.0)), 0.0)  # |dv|, gradient 0 at dv = 0
                K_kj = cd * tt * jnp.minimum(rho[k], rho[j]) * speed / length
            if k_lin is not None:
                K_kj = K_kj + k_lin * tt
            rows[k][j] = rows[j][k] = K_kj
    return rows


def exchange(
    m: jax.Array,
    v_star: jax.Array,
    Kmat: jax.Array | list[list[jax.Array | None]],
    dt: ArrayLike,
    V_n: jax.Array,
    m_min: ArrayLike,
    impulses: bool = False,
) -> jax.Array | tuple[jax.Array, jax.Array]:
    """(E3) implicit drag: solve m_k v_k + dt V_n sum_j K_kj (v_k - v_j) = m_k v*_k per node.
    m: (K, n), v_star: (K, n, d), Kmat: (K, K, n) (`drag_matrix`) or its nested lists
    (`drag_rows`), V_n: (n,). Returns the exchange force F_k = -V_n sum_j K_kj (v_k - v_j) at the
    implicit velocities, (K, n, d) in N: momentum moves only between fields (sum_k F_k = 0 to
    round-off) and the solve is stable for any drag. The K x K systems are unrolled over the fields
    with the nodes minor (`solve_rows`): elementwise loops over the nodes, no per-node matrices.
    impulses=True: returns (F, J), J (P, n, d) in N s the momentum each pair k < j of fields
    exchanged over the step, J_kj = dt V_n K_kj (v_k - v_j) (pairs in `field_pairs` order; F_k =
    -(sum_{j > k} J_kj - sum_{j < k} J_jk) / dt), for `drag_heat`."""
    n_f = m.shape[0]
    Kr = [[None if j == k else Kmat[k][j] for j in range(n_f)] for k in range(n_f)]
    empty = m <= m_min  # (K, n)
    a = [jnp.where(empty[k], 1.0, m[k]) for k in range(n_f)]
    c = [
        [None if j == k else jnp.where(empty[k] | empty[j], 0.0, dt * V_n * Kr[k][j]) for j in range(n_f)]
        for k in range(n_f)
    ]
    rhs = [m[k][:, None] * v_star[k] for k in range(n_f)]
    if n_f == 2:
        c12 = c[0][1]
        a1, a2 = a
        det = a1 * a2 + c12 * (a1 + a2)
        v = [
            ((a2 + c12)[:, None] * rhs[0] + c12[:, None] * rhs[1]) / det[:, None],
            ((a1 + c12)[:, None] * rhs[1] + c12[:, None] * rhs[0]) / det[:, None],
        ]
    else:
        A = [
            [a[k] + sum(c[k][i] for i in range(n_f) if i != k) if j == k else -c[k][j] for j in range(n_f)]
            for k in range(n_f)
        ]
        v = solve_rows(A, rhs)[0]
    F = [V_n[:, None] * sum(Kr[k][j][:, None] * (v[j] - v[k]) for j in range(n_f) if j != k) for k in range(n_f)]
    F = jnp.where(empty[..., None], 0.0, jnp.stack(F))
    if not impulses:
        return F
    return F, jnp.stack([c[k][j][:, None] * (v[k] - v[j]) for k, j in field_pairs(n_f)])


def field_pairs(n_fields: int) -> list[tuple[int, int]]:
    """The pairs (k, j), k < j, of n_fields velocity fields, in the order of `exchange`'s impulses."""
    return [(k, j) for k in range(n_fields) for j in range(k + 1, n_fields)]


def drag_heat(J: jax.Array, m: jax.Array, v: jax.Array, m_min: ArrayLike) -> jax.Array:
    """Heat of the exchange (our closure; scene option drag_heating), (K, n) in J per node and field.
    The drag does the work w_kj = J_kj . (v_k - v_j) on each pair of fields over the step: its
    power (E3) at the fields' velocities v (K, n, d) m/s, which `seed_update` takes from the remap
    of the particles' updated velocities (before E14), so that the sum over nodes equals the kinetic
    energy the exchange takes from the particles, sum_p m_p v_p^new . dt a_F,p. At the solve's own
    velocities w_kj = dt V_n K_kj |v_k - v_j|^2 >= 0; at the remapped ones it is negative only where
    their relative velocity opposes the solve's (cooling there, as the particles gain). Each pair's work is
    split as if the interface moved with the pair's centre of mass: field k takes m_j / (m_k + m_j)
    of it, so the lighter field heats more (two fields: each takes the change of its own kinetic
    energy in the centre-of-mass frame). J: (P, n, d) pair impulses (`exchange`); m: (K, n) kg."""
    n_f = m.shape[0]
    heat = [jnp.zeros_like(m[0]) for _ in range(n_f)]
    for J_kj, (k, j) in zip(J, field_pairs(n_f)):
        w = jnp.sum(J_kj * (v[k] - v[j]), -1)
        pair = m[k] + m[j]
        heat[k] = heat[k] + w * safe_div(m[j], pair, m_min)
        heat[j] = heat[j] + w * safe_div(m[k], pair, m_min)
    return jnp.stack(heat)


def ambient_pressure(theta: jax.Array, kappa: jax.Array, P: jax.Array) -> jax.Array:
    """Common pressure (E6) of the OTHER groups at each node, (K, n) Pa, for nodal volume fractions
    theta, compressibilities kappa (1/Pa) and pressures P (Pa) of K groups, each (K, n): the
    ambient pressure the fragmented part of group k relaxes to (E8), with the groups the phases
    (or the velocity fields, where each holds one phase); 0 where no other group is present."""
    tk = theta * kappa
    num = jnp.sum(tk * P, 0)[None] - tk * P
    den = jnp.sum(tk, 0)[None] - tk
    return safe_div(num, den, 1e-30 * jnp.max(den))
