"""Maxwell viscoelastic model of the seed (brittle Taylor impact), on the total stress with the
Jaumann rate:

    d sigma/dt - W sigma + sigma W = -sigma / tau + lambda tr(D) I + 2 G D

The relaxation term is integrated exactly over the step (sigma *= exp(-dt / tau)), so a held strain
relaxes as exp(-t / tau) at any dt; the elastic and spin terms are forward Euler as in hypoelastic.
Constants: rho0 (kg/m^3), E (Pa), nu, tau (s). In 1D, E is the bar modulus (as elastic.py).
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxmpm.materials.elastic import hypoelastic_update


def maxwell_update(c, F, stress, L, dt):
    """Relax the stress by exp(-dt / tau), then add the hypoelastic (Jaumann) increment."""
    relaxed = stress * jnp.exp(-dt / c["tau"])
    return hypoelastic_update(c, F, relaxed, L, dt)
