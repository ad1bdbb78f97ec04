"""Invariants of the hydrocode models' stresses and rates: traces, the von Mises stress, the
equivalent strain rate and the largest principal stress.

Geometry: s holds the in-plane components of the 3D deviator. In 2D plane strain s_zz = -tr(s); in
1D (uniaxial strain) s_yy = s_zz = -s_xx / 2; both follow from tr(s_3D) = 0 and keep J2 and the
principal stresses exact in every dimension.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def trace(A: jax.Array) -> jax.Array:
    """The trace of each matrix of A (..., d, d)."""
    return jnp.trace(A, axis1=-2, axis2=-1)


def deviator_norm2(s: jax.Array) -> jax.Array:
    """s:s of the full 3D deviator from its in-plane part (plane strain / uniaxial strain). (N,)"""
    d = s.shape[-1]
    ss = jnp.sum(s * s, axis=(-1, -2))
    return ss if d == 3 else ss + trace(s) ** 2 / (3 - d)


def _safe_sqrt(x, tiny=1e-30):
    return jnp.sqrt(jnp.maximum(x, tiny))


def equivalent_stress(s: jax.Array) -> jax.Array:
    """von Mises stress sqrt(3/2 s:s), Pa. (N,)"""
    return _safe_sqrt(1.5 * deviator_norm2(s))


def equivalent_rate(D: jax.Array) -> jax.Array:
    """sqrt(2/3 D':D') with D' the 3D deviator of D (out-of-plane D = 0). (N,) 1/s"""
    d = D.shape[-1]
    tr = trace(D)
    Dd = D - (tr / 3)[:, None, None] * jnp.eye(d, dtype=D.dtype)
    dd = jnp.sum(Dd * Dd, axis=(-1, -2)) + (3 - d) * (tr / 3) ** 2
    return _safe_sqrt(2.0 / 3.0 * dd)


def max_principal_stress(s: jax.Array, P: jax.Array) -> jax.Array:
    """Largest principal value of the full 3D stress s - P I (no gradient: it only switches). (N,)"""
    s, P = jax.lax.stop_gradient(s), jax.lax.stop_gradient(P)
    d = s.shape[-1]
    if d == 1:
        return jnp.maximum(s[:, 0, 0], -0.5 * s[:, 0, 0]) - P
    top = largest_eigenvalue_2x2(s) if d == 2 else largest_eigenvalue_3x3(s)
    if d == 2:
        top = jnp.maximum(top, -trace(s))
    return top - P


def largest_eigenvalue_2x2(s: jax.Array) -> jax.Array:
    """Largest eigenvalue of symmetric (N, 2, 2) matrices, in closed form. (N,)"""
    m = 0.5 * (s[:, 0, 0] + s[:, 1, 1])
    h = 0.5 * (s[:, 0, 0] - s[:, 1, 1])
    return m + jnp.sqrt(h * h + s[:, 0, 1] * s[:, 1, 0])


def largest_eigenvalue_3x3(s: jax.Array) -> jax.Array:
    """Largest eigenvalue of symmetric (N, 3, 3) matrices, in closed form (Smith, Commun. ACM 4
    (1961) 168: q = tr/3, p = sqrt(|s - qI|^2 / 6), lambda = q + 2 p cos(acos(det((s - qI)/p)/2)/3)).
    Closed form rather than LAPACK: no library call inside vmapped scans, and exact for p = 0. (N,)"""
    q = trace(s) / 3
    B = s - q[:, None, None] * jnp.eye(3, dtype=s.dtype)
    p = jnp.sqrt(jnp.sum(B * B, axis=(-1, -2)) / 6)
    safe = jnp.where(p > 0, p, 1.0)
    C = B / safe[:, None, None]
    det = (
        C[:, 0, 0] * (C[:, 1, 1] * C[:, 2, 2] - C[:, 1, 2] * C[:, 2, 1])
        - C[:, 0, 1] * (C[:, 1, 0] * C[:, 2, 2] - C[:, 1, 2] * C[:, 2, 0])
        + C[:, 0, 2] * (C[:, 1, 0] * C[:, 2, 1] - C[:, 1, 1] * C[:, 2, 0])
    )
    r = jnp.clip(det / 2, -1.0, 1.0)
    return q + jnp.where(p > 0, 2 * p * jnp.cos(jnp.arccos(r) / 3), 0.0)
