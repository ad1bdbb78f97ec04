"""Registry of constitutive model kinds: required constants with their allowed ranges, the update,
wave speeds and the initial state. Each kind's physics lives in its own module.

Two families:
  * one-piece kinds on the total stress: linear_elastic, hypoelastic, linear_fluid (elastic.py),
    maxwell and maxwell_brittle (viscoelastic.py), transversely_isotropic (anisotropic.py);
  * hydrocode compositions "eos[+strength][+failure...]" (hydro.py), e.g.
    "mie_gruneisen+johnson_cook_thermal+spall": the pressure from an equation of state p(rho, e)
    with the internal energy equation solved with it, a deviatoric strength model, failure criteria.
`model_of(name)` returns the Model of either.

All stress updates share one interface, update(c, mp, L, D, dt, work, q, alpha_of, force_work=None)
-> MatPoint:
  c        the constants (dict of scalars, SI)
  mp       MatPoint of the particles at the start of the step plus their density after it
  L        (N, d, d) velocity gradient seen by the material (1/s; with the closure E4 its
           isotropic part is the material volume rate)
  D        (N, d, d) rate of deformation of the velocity field (1/s), the rate the grid forces do
           work with
  dt       time step, s
  work     (N,) dt * V_mid / m, so that de = work * (sigma_f : D) (sigma_f: the stress the grid sees)
  q        (N,) artificial viscosity pressure at the end of the step (Pa) or None
  alpha_of eps_ps -> alpha (E5) or None without the closure: the grid sees s - alpha p I (E8)
  force_work (D_f (N, d, d) 1/s, w_f (N,) s m^3/kg, de_a (N,) J/kg or None) or None: the rate and
           weight of the work the grid's forces did this step and the ambient pressure's share
           (`jaxmpm.stages.constitutive`, energy_update 'compatible'); the hydrocode models then take
           de = w_f (sigma_f^n : D_f) + de_a, sigma_f^n the stress the grid saw, and the step
           conserves the total energy exactly. The total-stress kinds take the midpoint stress's work (their
           internal energy is the strain energy's account, not a state their stress depends on).
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp

from jaxmpm.materials import anisotropic, elastic, hydro, viscoelastic
from jaxmpm.materials.kind import MatPoint as MatPoint
from jaxmpm.materials.kind import Model

_POS = (0.0, math.inf, False, False)
_SOLID = {"rho0": _POS + ("kg/m^3",), "E": _POS + ("Pa",), "nu": (-1.0, 0.5, False, False, "")}


def _total_stress(fn, volumetric=False):
    """Wrap a total-stress update fn(c, F, stress, L, dt) -> (F, stress) in the common interface:
    pressure = -tr(stress) / d and the energy from the midpoint stress the grid sees. volumetric:
    fn also takes the density after the step, rho_new (N,) kg/m^3 (a fluid's state)."""

    def update(c, mp, L, D, dt, work, q, alpha_of, force_work=None):
        F, sig = fn(c, mp.F, mp.stress, L, dt, mp.rho_new) if volumetric else fn(c, mp.F, mp.stress, L, dt)
        if (
            q is not None
        ):  # artificial viscosity: nonzero only for linear_fluid here (scene.viscous_phases), whose stress is recomputed from F
            sig = sig - q[..., None, None] * jnp.eye(sig.shape[-1], dtype=sig.dtype)
        p = -jnp.trace(sig, axis1=-2, axis2=-1) / L.shape[-1]
        return mp._replace(
            F=F, stress=sig, pressure=p, energy=elastic.total_stress_energy(mp, sig, p, D, work, alpha_of)
        )

    return update


MODELS = {
    "linear_elastic": Model(
        _SOLID,
        _total_stress(elastic.linear_elastic_update),
        elastic.solid_wave_speed,
        elastic.solid_bulk_modulus,
        strain_energy=elastic.linear_elastic_energy,
    ),
    "hypoelastic": Model(
        _SOLID, _total_stress(elastic.hypoelastic_update), elastic.solid_wave_speed, elastic.solid_bulk_modulus
    ),
    "linear_fluid": Model(
        {"rho0": _POS + ("kg/m^3",), "K": _POS + ("Pa",)},
        _total_stress(elastic.linear_fluid_update, volumetric=True),
        elastic.fluid_wave_speed,
        elastic.fluid_bulk_modulus,
    ),
    "maxwell": Model(
        {**_SOLID, "tau": _POS + ("s",)},
        _total_stress(viscoelastic.maxwell_update),
        elastic.solid_wave_speed,
        elastic.solid_bulk_modulus,
    ),
    "maxwell_brittle": Model(
        {**_SOLID, "tau": _POS + ("s",), "sigma_t": _POS + ("Pa",), "tau_failed": _POS + ("s",)},
        viscoelastic.brittle_maxwell_update,
        elastic.solid_wave_speed,
        elastic.solid_bulk_modulus,
        can_fail=True,
    ),
    "transversely_isotropic": Model(
        anisotropic.CONSTANTS, _total_stress(anisotropic.update), anisotropic.wave_speed, anisotropic.bulk_modulus
    ),
}


def split_model(name: str, where: str = "model") -> tuple[str, tuple[str, ...], tuple[str, ...]]:
    """(eos, strength parts, failure parts) of a composite model name; ValueError naming `where`."""
    parts = name.split("+")
    eos = parts[0]
    if eos not in hydro.EOS:
        allowed = " | ".join(list(MODELS) + [f"{e}[+strength][+failure]" for e in hydro.EOS])
        raise ValueError(
            f"{where} = {name!r} is invalid: allowed {allowed}; strength: "
            f"{' | '.join(hydro.STRENGTH)}; failure: {' | '.join(hydro.FAILURE)}"
        )
    strength = tuple(p for p in parts[1:] if p in hydro.STRENGTH)
    failure = tuple(p for p in parts[1:] if p in hydro.FAILURE)
    unknown = [p for p in parts[1:] if p not in hydro.STRENGTH and p not in hydro.FAILURE]
    if unknown:
        raise ValueError(
            f"{where} = {name!r}: part {unknown[0]!r} is unknown: allowed strength "
            f"{' | '.join(hydro.STRENGTH)}, failure {' | '.join(hydro.FAILURE)}"
        )
    if len(strength) > 1:
        raise ValueError(f"{where} = {name!r} names {len(strength)} strength models: allowed at most one")
    if len(set(failure)) != len(failure):
        raise ValueError(f"{where} = {name!r} repeats a failure model")
    order = [eos] + list(strength) + list(failure)
    if parts != order:
        raise ValueError(f"{where} = {name!r} is out of order: write {'+'.join(order)!r} (eos, strength, failure)")
    return eos, strength, failure


@functools.lru_cache(maxsize=None)
def model_of(name: str) -> Model:
    """The Model of a kind name (one-piece or 'eos[+strength][+failure...]')."""
    if name in MODELS:
        return MODELS[name]
    eos, strength, failure = split_model(name)
    return hydro.compose(eos, strength[0] if strength else None, failure)


def model_names() -> str:
    """Human-readable list of the model kinds, for error messages."""
    return (
        " | ".join(MODELS)
        + " | eos[+strength][+failure...] with eos "
        + " | ".join(hydro.EOS)
        + ", strength "
        + " | ".join(hydro.STRENGTH)
        + ", failure "
        + " | ".join(hydro.FAILURE)
    )


def check_constant(model: str, name: str, value: float, where: str) -> None:
    """Raise ValueError naming `where` if `value` is outside the allowed range of `name`."""
    lo, hi, inc_lo, inc_hi, unit = model_of(model).constants[name]
    ok = math.isfinite(value) and (value >= lo if inc_lo else value > lo) and (value <= hi if inc_hi else value < hi)
    if not ok:
        rng = f"{'[' if inc_lo else '('}{lo:g}, {hi:g}{']' if inc_hi else ')'}"
        raise ValueError(f"{where} = {value!r} is invalid: allowed {rng}{' ' + unit if unit else ''}")
