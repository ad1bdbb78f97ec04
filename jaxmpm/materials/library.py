"""The material library (package copy of materials.toml) and `Material` specs.

A library key gives the material's full hydrocode model by default (see hydro.py):
  metals    mie_gruneisen + johnson_cook_thermal + spall (+ johnson_cook_failure or plastic_strain)
  concrete  linear + drucker_prager + spall
  air       ideal_gas (p0 = 1 atm);  water  stiffened_gas (p0 = 1 atm)
and any other model kind whose constants the table holds: `library_material("al2024",
"hypoelastic")` (rho0, E, nu), `library_material("water", "tait")`, `"linear_fluid"` (K = rho0 c^2 at
rest). Users define their own materials in a scene (Python or the `[materials.<key>]` tables of a
scene file, with `library = "<key>"` to start from a library entry and override constants).
"""

from __future__ import annotations

import functools
import numbers
import sys
import warnings
from dataclasses import dataclass
from importlib import resources
from typing import Any

import jax
import numpy as np

from jaxmpm.materials.models import MODELS, check_constant, model_of, split_model

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


@dataclass(frozen=True)
class Material:
    """A material: `key`, model kind and constants (SI) as a tuple of (name, value) pairs.
    Validated on construction, however built: `Material("x", "hypoelastic", (("rho0", 1e3), ...))`
    checks what `Material.make` checks, and stores the constants as floats in sorted order."""

    key: str
    model: str
    constants: tuple[tuple[str, float], ...]

    def __post_init__(self):
        where = f"materials.{self.key}"
        pairs = self.constants
        if isinstance(pairs, dict):
            pairs = tuple(pairs.items())
        if not (
            isinstance(pairs, (tuple, list))
            and all(isinstance(c, (tuple, list)) and len(c) == 2 and isinstance(c[0], str) for c in pairs)
        ):
            raise ValueError(
                f"{where}.constants = {self.constants!r} is invalid: allowed a tuple of (name, value) "
                "pairs, e.g. (('rho0', 1000.0), ('E', 1e9), ('nu', 0.3)); or use Material.make"
            )
        names = [c[0] for c in pairs]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})[0]
            raise ValueError(f"{where}.{dup} is given twice: allowed each constant once")
        vals = _checked_constants(self.key, self.model, dict(pairs))
        object.__setattr__(self, "constants", tuple(vals.items()))
        warn_implausible_units(where, self.model, vals, stacklevel=_outside_this_module())

    @staticmethod
    def make(key: str, model: str, **constants: float) -> "Material":
        """Build and validate; constants in SI units (rho0 kg/m^3, moduli and pressures Pa, speeds m/s,
        temperatures K, times s: each model's table in jaxmpm.materials.models gives the unit of
        each), e.g. Material.make("bar", "linear_elastic", rho0=1.0, E=100.0, nu=0.0) or
        Material.make("gas", "ideal_gas", rho0=1.0, gamma=1.4, p0=1.0). Model kinds:
        jaxmpm.materials.models (one-piece kinds and `'eos[+strength][+failure...]'` compositions)."""
        return Material(key, model, tuple(constants.items()))

    def as_dict(self) -> dict[str, float]:
        return dict(self.constants)

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, **self.as_dict()}


def _outside_this_module() -> int:
    """The `stacklevel` that makes a warning issued by `warn_implausible_units`, called from
    Material.__post_init__, name the first frame outside this module and the dataclass's generated
    __init__: the user's line that made the Material, by `Material(...)` or `Material.make`."""
    frame, level = sys._getframe(1), 2  # __post_init__ is level 2 as seen from the warning
    while frame is not None:
        inner = frame
        frame, level = frame.f_back, level + 1
        generated_init = (
            frame is not None
            and frame.f_code.co_filename == "<string>"
            and frame.f_code.co_name == "__init__"
            and inner.f_code.co_name == "__post_init__"
        )
        if frame is None or not (frame.f_code.co_filename == __file__ or generated_init):
            return level
    return level


def _checked_constants(key, model, constants: dict) -> dict[str, float]:
    """The constants of a material of `model` as floats in sorted order, each checked against its
    model's allowed range; a ValueError naming materials.KEY.NAME and what is allowed otherwise."""
    where = f"materials.{key}"
    if not isinstance(key, str) or not key.isidentifier():
        raise ValueError(f"materials key {key!r} is invalid: allowed an identifier")
    if not isinstance(model, str):
        raise ValueError(f"{where}.model = {model!r} is invalid: allowed a model name")
    if model not in MODELS:
        split_model(model, f"{where}.model")
    needed = model_of(model).constants
    unknown = sorted(set(constants) - set(needed))
    if unknown:
        raise ValueError(f"{where}.{unknown[0]} is not a constant of model {model!r}: allowed {sorted(needed)}")
    missing = sorted(set(needed) - set(constants))
    if missing:
        raise ValueError(f"{where}.{missing[0]} is missing: model {model!r} needs {sorted(needed)}")
    vals = {}
    for k in sorted(needed):
        v = constants[k]
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
            raise ValueError(f"{where}.{k} = {v!r} is invalid: allowed a number")
        check_constant(model, k, float(v), f"{where}.{k}")
        vals[k] = float(v)
    return vals


# Above these a material at rest is not a real one: the densest element (osmium) has 22,590 kg/m^3,
# the fastest longitudinal sound speed (diamond) is about 18 km/s.
DENSEST = 2.5e4  # kg/m^3
FASTEST = 2.5e4  # m/s


def warn_implausible_units(where: str, model: str, constants: dict, stacklevel: int = 3) -> None:
    """A UserWarning when a material's density or its longitudinal wave speed at rest (at rho0)
    is beyond any real material's: the usual sign of constants not in SI units (rho0 in g/cm^3
    makes the wave speed 32x too fast). Only a warning: scaled, non-dimensional constants are
    legitimate (the built-in elastic impact's wave speed is 1.16 m/s)."""
    rho0 = constants.get("rho0")
    if rho0 is None:
        return
    m = model_of(model)
    with jax.ensure_compile_time_eval():  # materials are also resolved while a step is traced
        e0 = m.initial(constants)[1]
        c0 = float(np.asarray(m.wave_speed(constants, np.array([rho0]), np.array([float(e0)]), 3))[0])
    if rho0 > DENSEST:
        warnings.warn(
            f"{where}.rho0 = {rho0:g} kg/m^3 is denser than any real material (osmium: 22,590): "
            "density is in kg/m^3 (1 g/cm^3 = 1000 kg/m^3)",
            UserWarning,
            stacklevel=stacklevel,
        )
    if c0 > FASTEST:
        warnings.warn(
            f"{where}: its wave speed at rest is {c0:,.0f} m/s, faster than any real material's "
            "(diamond: about 18,000): are the constants in SI units (rho0 in kg/m^3, moduli in Pa)? "
            "With rho0 in g/cm^3 the speed comes out 32x too fast",
            UserWarning,
            stacklevel=stacklevel,
        )


CHECK_FIELDS = ("checked", "read", "derived", "note")


def _data(name: str) -> dict:
    return tomllib.loads(resources.files("jaxmpm").joinpath(f"data/{name}").read_text())


def merge_checks(table: dict, checks: dict) -> dict:
    """materials.toml's table with the project's checks (verification.toml) merged over it: a checked
    sub-table takes the check's `verified`, `source` and replaced `values`, and keeps the rest of the
    check under "checks". A check must name an existing sub-table and constants."""
    for key, subs in checks.items():
        for sub, check in subs.items():
            where = f"verification.toml [{key}.{sub}]"
            if sub not in table.get(key, {}) or not isinstance(table[key][sub], dict):
                raise ValueError(f"{where} names no sub-table of materials.toml")
            unknown = sorted(set(check) - {"verified", "source", "values", *CHECK_FIELDS})
            if unknown:
                raise ValueError(
                    f"{where}.{unknown[0]} is unknown: allowed verified, source, values, {', '.join(CHECK_FIELDS)}"
                )
            t = table[key][sub]
            for name, value in check.get("values", {}).items():
                if name not in t:
                    raise ValueError(f"{where}.values.{name} is not a constant of materials.toml's [{key}.{sub}]")
                t[name] = value
            t.update({k: check[k] for k in ("verified", "source") if k in check})
            t["checks"] = {k: check[k] for k in CHECK_FIELDS if k in check}
    return table


@functools.lru_cache(maxsize=1)
def library_table() -> dict:
    """The package's materials.toml (the shared table: constants with their sources) with the
    project's checks of it (data/verification.toml) merged over it (`merge_checks`)."""
    return merge_checks(_data("materials.toml"), _data("verification.toml"))


def known_keys() -> tuple[str, ...]:
    """The material keys of the library, sorted."""
    return tuple(sorted(library_table()))


# The sub-tables whose numbers the models read, in order of precedence (a name found in an earlier
# one is taken from it); the table's other sub-tables (alternative fits) are for reference only.
USED_TABLES = ("eos", "elastic", "strength", "thermal", "spall", "failure", "tait")


def _entry(key: str) -> dict:
    table = library_table()
    if key not in table:
        raise ValueError(f"material key {key!r} is unknown: known keys are {list(known_keys())}")
    return table[key]


def constant_origins(key: str, model: str | None = None) -> dict[str, tuple[float, str]]:
    """Every constant the library holds for `key`, under the names the model kinds use, with the
    sub-table it is read from: name -> (value, sub-table). A value derived from others (a fluid's
    bulk modulus at rest) names the sub-table of its inputs. With a `model` whose EOS is 'tait',
    the tait sub-table's own rho0 and p0 come first (its fit's reference state)."""
    entry = _entry(key)
    eos = entry["eos"]
    pool: dict[str, tuple[float, str]] = {}
    for sub in USED_TABLES[:-1]:
        for k, v in entry.get(sub, {}).items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                pool.setdefault(k, (float(v), sub))
    if "tait" in entry:
        pool["tait_n"], pool["tait_B"] = (float(entry["tait"]["n"]), "tait"), (float(entry["tait"]["B"]), "tait")
        if isinstance(model, str) and model.split("+")[0] == "tait":
            pool.update({k: (float(entry["tait"][k]), "tait") for k in ("rho0", "p0") if k in entry["tait"]})
    if "elastic" not in entry:  # fluids: bulk modulus at rest for linear_fluid
        if eos["model"] == "ideal_gas":
            pool["K"] = (eos["gamma"] * eos["p0"], "eos")
        elif eos["model"] == "stiffened_gas":
            pool["K"] = (eos["gamma"] * (eos["p0"] + eos["p_inf"]), "eos")
    return pool


def library_constants(key: str, model: str | None = None) -> dict[str, float]:
    """Every constant the library holds for `key`, under the names the model kinds use (for `model`:
    `constant_origins`)."""
    return {k: v for k, (v, _) in constant_origins(key, model).items()}


def table_provenance(key: str) -> dict[str, tuple[str, bool, dict]]:
    """sub-table -> (source, verified, checks) for every sub-table of `key`'s library entry. verified:
    every number of the sub-table was read in its source (a derived one's arithmetic checked); False:
    at least one awaits that check. checks: the project's record of its check (data/verification.toml:
    checked, read, derived, note), {} where there is none."""
    return {
        sub: (t.get("source", ""), bool(t.get("verified", False)), t.get("checks", {}))
        for sub, t in _entry(key).items()
        if isinstance(t, dict)
    }


def default_model(key: str) -> str:
    """The full model kind of a library key (module docstring)."""
    entry = _entry(key)
    parts = [entry["eos"]["model"]]
    strength = entry.get("strength", {}).get("model")
    if strength == "johnson_cook":
        parts.append("johnson_cook_thermal" if "thermal" in entry else "johnson_cook")
    elif strength == "pressure_dependent":
        parts.append("drucker_prager")
    if "spall" in entry:
        parts.append("spall")
    failure = entry.get("failure", {}).get("model")
    if failure in ("johnson_cook_failure", "plastic_strain"):
        parts.append(failure)
    return "+".join(parts)


def library_material(key: str, model: str | None = None, new_key: str | None = None, **overrides: float) -> Material:
    """The Material of a library key with its default model (or `model`), constants from the table
    and `overrides` on top; named `new_key` (default: key)."""
    model = default_model(key) if model is None else model
    pool = library_constants(key, model)
    name = key if new_key is None else new_key
    needed = model_of(model).constants if isinstance(model, str) else {}
    missing = sorted(k for k in needed if k not in pool and k not in overrides)
    if missing:
        raise ValueError(
            f"materials.{name}: library key {key!r} has no {missing[0]!r} for model {model!r}: "
            f"give it (materials.{name}.{missing[0]} = ...) or choose another model"
        )
    return Material.make(name, model, **{**{k: pool[k] for k in needed if k in pool}, **overrides})


def resolve_material(spec: Any, user: tuple = (), where: str = "material") -> Material:
    """Material for a phase: a Material, a key among the scene's own materials, or a library key."""
    if isinstance(spec, Material):
        return spec
    if not isinstance(spec, str):
        raise ValueError(f"{where} = {spec!r} is invalid: allowed a material key or a Material")
    for m in user:
        if m.key == spec:
            return m
    if spec in library_table():
        return library_material(spec)
    known = sorted({m.key for m in user} | set(known_keys()))
    raise ValueError(f"{where} = {spec!r} is an unknown material key: known keys are {known}")
