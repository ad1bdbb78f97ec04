"""Registry of constitutive model kinds: required constants with their allowed ranges, the
stress update and the longitudinal wave speed. Each kind's physics lives in its own module."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from jaxmpm.materials import elastic


@dataclass(frozen=True)
class Model:
    """A constitutive model kind.

    constants: name -> (low, high, inclusive_low, inclusive_high, unit) allowed range.
    update(c, F, stress, L, dt) -> (F, stress): c the constants (dict of scalars), F and stress
      (N, d, d), L the velocity gradient (N, d, d) in 1/s, dt in s.
    wave_speed(c, rho, dim) -> (N,) longitudinal wave speed in m/s at density rho (kg/m^3).
    bulk_modulus(c, rho, dim) -> (N,) bulk modulus K in Pa (compressibility kappa = 1 / K, E6).
    strain_energy(c, F) -> (N,) elastic energy per reference volume (J/m^3), where defined.
    """

    constants: dict
    update: Callable
    wave_speed: Callable
    bulk_modulus: Callable
    strain_energy: Callable | None = None


_SOLID = {"rho0": (0.0, float("inf"), False, False, "kg/m^3"),
          "E": (0.0, float("inf"), False, False, "Pa"),
          "nu": (-1.0, 0.5, False, False, "")}

MODELS = {
    "linear_elastic": Model(_SOLID, elastic.linear_elastic_update, elastic.solid_wave_speed,
                            elastic.solid_bulk_modulus, elastic.linear_elastic_energy),
    "hypoelastic": Model(_SOLID, elastic.hypoelastic_update, elastic.solid_wave_speed, elastic.solid_bulk_modulus),
    "linear_fluid": Model({"rho0": (0.0, float("inf"), False, False, "kg/m^3"),
                           "K": (0.0, float("inf"), False, False, "Pa")},
                          elastic.linear_fluid_update, elastic.fluid_wave_speed, elastic.fluid_bulk_modulus),
}


def check_constant(model: str, name: str, value: float, where: str) -> None:
    """Raise ValueError naming `where` if `value` is outside the allowed range of `name`."""
    import math

    lo, hi, inc_lo, inc_hi, unit = MODELS[model].constants[name]
    ok = math.isfinite(value) and (value >= lo if inc_lo else value > lo) and (value <= hi if inc_hi else value < hi)
    if not ok:
        rng = f"{'[' if inc_lo else '('}{lo:g}, {hi:g}{']' if inc_hi else ')'}"
        raise ValueError(f"{where} = {value!r} is invalid: allowed {rng}{' ' + unit if unit else ''}")
