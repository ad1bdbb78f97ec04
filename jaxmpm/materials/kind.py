"""Model: what a constitutive model kind provides (its constants' ranges, stress update, wave
speed, bulk modulus, state at rest). The kinds themselves are registered in `models`. Part: one
part of a hydrocode composition (`hydro`), and the shorthands of the constants' allowed ranges.
MatPoint: the particles' material state that a stress update takes and returns; Constants: a
model's constants by name."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping, NamedTuple

import jax
from jax.typing import ArrayLike

INF = math.inf
POS = (0.0, INF, False, False)  # > 0
NONNEG = (0.0, INF, True, False)  # >= 0
ANY = (-INF, INF, False, False)

# a model's constants by name (SI): numbers, or arrays of one value per particle under jax.vmap
Constants = Mapping[str, ArrayLike]


class MatPoint(NamedTuple):
    """Per-particle material state (N leading axis): F (N,d,d), stress (N,d,d) Pa, pressure (N,) Pa
    (the isotropic pressure the stress holds, including artificial viscosity: for the hydrocode
    models stress = s - pressure I with s the in-plane part of the 3D deviator), energy (N,) J/kg,
    eps_ps (N,) equivalent plastic strain, damage (N,) in [0, 1] (1: failed), rho (N,) kg/m^3 at
    the start of the step, rho_new (N,) after it."""

    F: jax.Array
    stress: jax.Array
    pressure: jax.Array
    energy: jax.Array
    eps_ps: jax.Array
    damage: jax.Array
    rho: jax.Array
    rho_new: jax.Array


@dataclass(frozen=True)
class Part:
    """One part of a hydrocode composition (an equation of state, a strength or a failure
    criterion): its constants (name -> (lo, hi, inc_lo, inc_hi, unit)), and for an equation of
    state its coefficients fn(c, rho) -> (A, B) and its state at rest initial(c) -> (p0, e0)."""

    constants: dict
    fn: Callable | None = None
    initial: Callable | None = None


@dataclass(frozen=True)
class Model:
    """A constitutive model kind.

    constants: name -> (low, high, inclusive_low, inclusive_high, unit) allowed range.
    update: see the module docstring.
    wave_speed(c, rho, e, dim) -> (N,) longitudinal wave speed (m/s) at density rho (kg/m^3) and
      specific internal energy e (J/kg): the CFL speed.
    bulk_modulus(c, rho, e, dim) -> (N,) bulk modulus K in Pa (compressibility kappa = 1 / K, E6).
    initial(c) -> (p0, e0): pressure (Pa) and specific internal energy (J/kg) at rest at rho0.
    strain_energy(c, F) -> (N,) elastic energy per reference volume (J/m^3), where defined.
    hydro: whether the model is a hydrocode composition (its stress = deviator - pressure I).
    can_fail: whether the update sets damage (one-piece kinds; a composition fails through its parts).
    """

    constants: dict
    update: Callable
    wave_speed: Callable
    bulk_modulus: Callable
    initial: Callable = lambda c: (0.0, 0.0)
    strain_energy: Callable | None = None
    hydro: bool = False
    can_fail: bool = False
