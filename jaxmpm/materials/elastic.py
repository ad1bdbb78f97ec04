"""Elastic models: linear elastic (small strain in F), hypoelastic with the Jaumann rate, and a
linear fluid p = -K (J - 1). In 1D, E is the bar (uniaxial stress) modulus: sigma = E eps.

linear_elastic uses eps = sym(F) - I, exact for small deformations (verification problems) but not
objective: under large rotations it makes spurious stress (two soft disks bouncing in a box for
17 s collapse with it; with hypoelastic they run 33 s within 1% energy). Use hypoelastic for large
deformations.

Shapes: F, stress, L are (N, d, d); constants are scalars (or broadcastable); SI units.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxmpm.materials.kind import Constants, MatPoint


def lame(c: Constants, dim: int) -> tuple[jax.Array, jax.Array]:
    """Lame constants (lambda, mu) in Pa from E, nu; in 1D (lambda, mu) = (0, E / 2)."""
    E, nu = c["E"], c["nu"]
    if dim == 1:
        return jnp.zeros_like(E), 0.5 * E
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _sym(A):
    return 0.5 * (A + jnp.swapaxes(A, -1, -2))


def _trace(A):
    return jnp.trace(A, axis1=-2, axis2=-1)


def update_F(F: jax.Array, L: jax.Array, dt: ArrayLike) -> jax.Array:
    """F_{n+1} = (I + dt L) F_n (deformation gradient, forward update)."""
    eye = jnp.eye(F.shape[-1], dtype=F.dtype)
    return jnp.matmul(eye + dt * L, F)


def linear_elastic_stress(c: Constants, F: jax.Array) -> jax.Array:
    """sigma = lambda tr(eps) I + 2 mu eps, eps = sym(F) - I (small strain)."""
    d = F.shape[-1]
    lam, mu = lame(c, d)
    eye = jnp.eye(d, dtype=F.dtype)
    eps = _sym(F) - eye
    return lam * _trace(eps)[..., None, None] * eye + 2 * mu * eps


def linear_elastic_update(
    c: Constants, F: jax.Array, stress: jax.Array, L: jax.Array, dt: ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """F_{n+1} = (I + dt L) F_n and sigma from it (small strain; not objective)."""
    F = update_F(F, L, dt)
    return F, linear_elastic_stress(c, F)


def linear_elastic_energy(c: Constants, F: jax.Array) -> jax.Array:
    """W = lambda/2 tr(eps)^2 + mu eps:eps per reference volume (J/m^3)."""
    d = F.shape[-1]
    lam, mu = lame(c, d)
    eps = _sym(F) - jnp.eye(d, dtype=F.dtype)
    return 0.5 * lam * _trace(eps) ** 2 + mu * jnp.sum(eps * eps, axis=(-1, -2))


def hypoelastic_update(
    c: Constants, F: jax.Array, stress: jax.Array, L: jax.Array, dt: ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """Jaumann rate: d sigma/dt = lambda tr(D) I + 2 mu D + W sigma - sigma W."""
    d = F.shape[-1]
    lam, mu = lame(c, d)
    D = _sym(L)
    W = 0.5 * (L - jnp.swapaxes(L, -1, -2))
    eye = jnp.eye(d, dtype=F.dtype)
    rate = lam * _trace(D)[..., None, None] * eye + 2 * mu * D + W @ stress - stress @ W
    return update_F(F, L, dt), stress + dt * rate


def linear_fluid_update(
    c: Constants, F: jax.Array, stress: jax.Array, L: jax.Array, dt: ArrayLike, rho_new: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """p = -K (J - 1), sigma = -p I. J = rho0 / rho_new, the particle's volume ratio after the step
    (the volume the grid forces act on), with F = J^(1/d) I: a fluid keeps no shear. rho_new None:
    J = det F of the forward update F = (I + dt L) F, which drifts from the volume ratio where L
    has a large rotational or shear part (det(I + dt L) = 1 + dt tr L + dt^2 det L in 2D against
    the volume's exp(dt tr L)): splashed particles then held a pressure of the opposite sign to
    their volume change and were driven apart."""
    d = F.shape[-1]
    eye = jnp.eye(d, dtype=F.dtype)
    if rho_new is None:
        F = update_F(F, L, dt)
        J = jnp.linalg.det(F) if d > 1 else F[..., 0, 0]
    else:
        J = c["rho0"] / rho_new
        F = J[..., None, None] ** (1.0 / d) * eye
    return F, (c["K"] * (J - 1))[..., None, None] * eye


def solid_wave_speed(c: Constants, rho: jax.Array, e: jax.Array, dim: int) -> jax.Array:
    """Longitudinal speed sqrt((lambda + 2 mu) / rho); 1D: sqrt(E / rho)."""
    lam, mu = lame(c, dim)
    return jnp.sqrt((lam + 2 * mu) / rho)


def fluid_wave_speed(c: Constants, rho: jax.Array, e: jax.Array, dim: int) -> jax.Array:
    """sqrt(K / rho), m/s."""
    return jnp.sqrt(c["K"] / rho)


def solid_bulk_modulus(c: Constants, rho: jax.Array, e: jax.Array, dim: int) -> jax.Array:
    """K = E / (3 (1 - 2 nu)); in 1D the bar modulus E (the only volumetric stiffness there)."""
    if dim == 1:
        return c["E"] * jnp.ones_like(rho)
    return c["E"] / (3 * (1 - 2 * c["nu"])) * jnp.ones_like(rho)


def fluid_bulk_modulus(c: Constants, rho: jax.Array, e: jax.Array, dim: int) -> jax.Array:
    """K, Pa."""
    return c["K"] * jnp.ones_like(rho)


def total_stress_energy(
    mp: MatPoint,
    sig: jax.Array,
    p: jax.Array,
    D: jax.Array,
    work: jax.Array,
    alpha_of: Callable[[jax.Array], jax.Array] | None,
) -> jax.Array:
    """Specific internal energy (N,) J/kg after a total-stress update to `sig` (N, d, d) with pressure
    p = -tr(sig) / d: the work of the midpoint stress the grid sees over the step, de = work *
    sigma_f : D, with the closure's alpha p (E8) where `alpha_of` is given."""
    d = sig.shape[-1]
    a = 1.0 if alpha_of is None else alpha_of(mp.eps_ps)[:, None, None]
    eye = jnp.eye(d, dtype=sig.dtype)
    sig_f = 0.5 * (mp.stress + sig) + (1 - a) * (0.5 * (mp.pressure + p))[:, None, None] * eye
    return mp.energy + work * jnp.sum(sig_f * D, axis=(-1, -2))
