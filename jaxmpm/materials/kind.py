"""Model: what a constitutive model kind provides (its constants' ranges, stress update, wave
speed, bulk modulus, state at rest). The kinds themselves are registered in `models`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


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
