"""Maxwell viscoelastic model of the seed (brittle Taylor impact), on the total stress with the
Jaumann rate:

    d sigma/dt - W sigma + sigma W = -sigma / tau + lambda tr(D) I + 2 G D

The relaxation term is integrated exactly over the step (sigma *= exp(-dt / tau)), so a held strain
relaxes as exp(-t / tau) at any dt; the elastic and spin terms are forward Euler as in hypoelastic.
Constants: rho0 (kg/m^3), E (Pa), nu, tau (s). In 1D, E is the bar modulus (as elastic.py).
`maxwell_brittle` adds damage: tensile strength sigma_t (Pa) and the failed material's relaxation
time tau_failed (s) (`brittle_maxwell_update`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxmpm.materials.elastic import hypoelastic_update, total_stress_energy
from jaxmpm.materials.kind import Constants, MatPoint


def maxwell_update(
    c: Constants, F: jax.Array, stress: jax.Array, L: jax.Array, dt: ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """Relax the stress by exp(-dt / tau), then add the hypoelastic (Jaumann) increment."""
    relaxed = stress * jnp.exp(-dt / c["tau"])
    return hypoelastic_update(c, F, relaxed, L, dt)


def brittle_maxwell_update(
    c: Constants,
    mp: MatPoint,
    L: jax.Array,
    D: jax.Array,
    dt: ArrayLike,
    work: jax.Array,
    q: jax.Array | None,
    alpha_of: Callable[[jax.Array], jax.Array] | None,
    force_work: tuple | None = None,
) -> MatPoint:
    """Maxwell model with a damage-dependent relaxation time, for brittle material (the seed's
    brittle Taylor impact). Intact (damage 0): `maxwell_update` with tau. A particle fails (damage
    1, for good) on the step its intact update would give a largest principal stress above the
    tensile strength sigma_t; failed material (from that step on) relaxes its deviatoric stress with
    tau_failed (<< tau: it flows as rubble) and carries no tension (its pressure is floored at 0),
    the failure convention of the hydrocode models.
    Energy: the work of the midpoint stress, as the total-stress models (`total_stress_energy`)."""
    d = L.shape[-1]
    eye = jnp.eye(d, dtype=mp.stress.dtype)
    F, intact = hypoelastic_update(c, mp.F, mp.stress * jnp.exp(-dt / c["tau"]), L, dt)
    damage = jnp.where(jnp.linalg.eigvalsh(intact)[..., -1] > c["sigma_t"], 1.0, mp.damage)
    p_old = -jnp.trace(mp.stress, axis1=-2, axis2=-1) / d
    dev_old = mp.stress + p_old[:, None, None] * eye
    _, broken = hypoelastic_update(
        c, mp.F, dev_old * jnp.exp(-dt / c["tau_failed"]) - p_old[:, None, None] * eye, L, dt
    )
    p_broken = -jnp.trace(broken, axis1=-2, axis2=-1) / d
    broken = broken + (p_broken - jnp.maximum(p_broken, 0.0))[:, None, None] * eye  # no tension
    sig = jnp.where((damage >= 1.0)[:, None, None], broken, intact)
    p = -jnp.trace(sig, axis1=-2, axis2=-1) / d
    return mp._replace(
        F=F, stress=sig, pressure=p, energy=total_stress_energy(mp, sig, p, D, work, alpha_of), damage=damage
    )
