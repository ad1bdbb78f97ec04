"""Transversely isotropic elastic model for fibre composites, rotated with the material.

Material frame: axis 1 along the fibre, 2 and 3 transverse (the isotropic plane). Compliance
(Voigt order 11, 22, 33, 23, 13, 12; engineering shear strains):

    S = [[1/E1, -nu12/E1, -nu12/E1], [-nu12/E1, 1/E2, -nu23/E2], [-nu12/E1, -nu23/E2, 1/E2]]
        (+) diag(1/G23, 1/G12, 1/G12),   G23 = E2 / (2 (1 + nu23)),

C = S^-1 as a fourth-order tensor, rotated to the reference frame by the initial fibre direction
a0 = (cos theta cos phi, sin theta cos phi, sin phi) (fibre_theta in the x-y plane from x, fibre_phi
towards z), and restricted to the first d axes (plane strain in 2D, uniaxial strain in 1D).

Update (Green-Naghdi): with R from the polar decomposition F = R U, the rotated stress
sigma^ = R^T sigma R obeys d sigma^/dt = C : (R^T D R); the fibre of each particle turns with its
own R, so the direction is carried per particle. Constants: rho0, E1, E2, nu12, nu23, G12 (SI),
fibre_theta, fibre_phi (rad).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from jaxmpm.materials.kind import Constants

_P = (0.0, math.inf, False, False)
CONSTANTS = {
    "rho0": _P + ("kg/m^3",),
    "E1": _P + ("Pa",),
    "E2": _P + ("Pa",),
    "nu12": (-1.0, 0.5, False, False, ""),
    "nu23": (-1.0, 1.0, False, False, ""),
    "G12": _P + ("Pa",),
    "fibre_theta": (-2 * math.pi, 2 * math.pi, True, True, "rad"),
    "fibre_phi": (-0.5 * math.pi, 0.5 * math.pi, True, True, "rad"),
}
_VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))
_VOIGT_INDEX = np.array([[_VOIGT.index((min(a, b), max(a, b))) for b in range(3)] for a in range(3)])  # (3, 3)


def voigt_stiffness(c: Constants) -> tuple[jax.Array, jax.Array]:
    """6x6 stiffness in the material frame (Voigt, engineering shear strains), Pa."""
    E1, E2, n12, n23, G12 = c["E1"], c["E2"], c["nu12"], c["nu23"], c["G12"]
    G23 = E2 / (2 * (1 + n23))
    z = jnp.zeros_like(E1)
    S = jnp.array(
        [
            [1 / E1, -n12 / E1, -n12 / E1, z, z, z],
            [-n12 / E1, 1 / E2, -n23 / E2, z, z, z],
            [-n12 / E1, -n23 / E2, 1 / E2, z, z, z],
            [z, z, z, 1 / G23, z, z],
            [z, z, z, z, 1 / G12, z],
            [z, z, z, z, z, 1 / G12],
        ]
    )
    return jnp.linalg.inv(S), S


def fibre_frame(c: Constants) -> jax.Array:
    """3x3 rotation whose columns are the material axes (fibre first) in the reference frame."""
    th, ph = c["fibre_theta"], c["fibre_phi"]
    a1 = jnp.stack([jnp.cos(th) * jnp.cos(ph), jnp.sin(th) * jnp.cos(ph), jnp.sin(ph)])
    a2 = jnp.stack([-jnp.sin(th), jnp.cos(th), jnp.zeros_like(th)])
    return jnp.stack([a1, a2, jnp.cross(a1, a2)], axis=1)


def stiffness_tensor(c: Constants, dim: int) -> jax.Array:
    """C_ijkl in the reference frame, restricted to the first `dim` axes. (d, d, d, d) Pa."""
    Cv, _ = voigt_stiffness(c)
    C = Cv[_VOIGT_INDEX[:, :, None, None], _VOIGT_INDEX[None, None, :, :]]  # one gather: C_abef = Cv[V(ab), V(ef)]
    Q = fibre_frame(c)
    C = jnp.einsum("ia,jb,kc,ld,abcd->ijkl", Q, Q, Q, Q, C)
    return C[:dim, :dim, :dim, :dim]


def polar_rotation(F: jax.Array) -> jax.Array:
    """R of the polar decomposition F = R U. (N, d, d)"""
    d = F.shape[-1]
    if d == 1:
        return jnp.sign(F)
    if d == 2:
        a = jnp.arctan2(F[:, 1, 0] - F[:, 0, 1], F[:, 0, 0] + F[:, 1, 1])
        c, s = jnp.cos(a), jnp.sin(a)
        return jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)
    R = F
    for _ in range(8):  # Higham's iteration R <- (R + R^-T) / 2
        R = 0.5 * (R + jnp.swapaxes(jnp.linalg.inv(R), -1, -2))
    return R


def update(c: Constants, F: jax.Array, stress: jax.Array, L: jax.Array, dt: ArrayLike) -> tuple[jax.Array, jax.Array]:
    d = L.shape[-1]
    C = stiffness_tensor(c, d)
    F_new = jnp.matmul(jnp.eye(d, dtype=F.dtype) + dt * L, F)
    R0, R1, Rm = polar_rotation(F), polar_rotation(F_new), polar_rotation(0.5 * (F + F_new))
    D = 0.5 * (L + jnp.swapaxes(L, -1, -2))
    RT = lambda R: jnp.swapaxes(R, -1, -2)
    s_hat = RT(R0) @ stress @ R0 + dt * jnp.einsum("ijkl,nkl->nij", C, RT(Rm) @ D @ Rm)
    return F_new, R1 @ s_hat @ RT(R1)


def wave_speed(c: Constants, rho: jax.Array, e: jax.Array, dim: int) -> jax.Array:
    """Upper bound of the longitudinal speed: sqrt(lambda_max(Mandel stiffness) / rho), m/s (no
    gradient: it only sets the CFL step)."""
    Cv, _ = voigt_stiffness(jax.lax.stop_gradient(c))
    w = jnp.array([1.0, 1.0, 1.0, 2.0**0.5, 2.0**0.5, 2.0**0.5], Cv.dtype)
    M = Cv * w[:, None] * w[None, :]
    return jnp.sqrt(jnp.linalg.eigvalsh(M)[-1] / rho)


def bulk_modulus(c: Constants, rho: jax.Array, e: jax.Array, dim: int) -> jax.Array:
    """Reuss bulk modulus 1 / sum_ij S_ij (i, j normal components), Pa."""
    _, S = voigt_stiffness(c)
    return jnp.ones_like(rho) / jnp.sum(S[:3, :3])
