"""The material library (package copy of materials.toml) and `Material` specs.

Library keys give, for now, the elastic part of each material: solids as `hypoelastic` with
rho0 (eos table), E and nu (elastic table); fluids as `linear_fluid` with K = rho0 c0^2 at the
reference state. Users define their own materials in a scene (Python or the `[materials.<key>]`
tables of a scene file).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources
from typing import Any

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


@dataclass(frozen=True)
class Material:
    """A material: `key`, model kind and constants (SI) as a tuple of (name, value) pairs."""

    key: str
    model: str
    constants: tuple[tuple[str, float], ...]

    @staticmethod
    def make(key: str, model: str, **constants: float) -> "Material":
        """Build and validate, e.g. Material.make("bar", "linear_elastic", rho0=1.0, E=100.0, nu=0.0)."""
        from jaxmpm.materials.models import MODELS, check_constant

        where = f"materials.{key}"
        if not isinstance(key, str) or not key.isidentifier():
            raise ValueError(f"materials key {key!r} is invalid: allowed an identifier")
        if model not in MODELS:
            raise ValueError(f"{where}.model = {model!r} is invalid: allowed {' | '.join(MODELS)}")
        needed = MODELS[model].constants
        unknown = sorted(set(constants) - set(needed))
        if unknown:
            raise ValueError(f"{where}.{unknown[0]} is not a constant of model {model!r}: allowed {sorted(needed)}")
        missing = sorted(set(needed) - set(constants))
        if missing:
            raise ValueError(f"{where}.{missing[0]} is missing: model {model!r} needs {sorted(needed)}")
        vals = {}
        for k in sorted(needed):
            v = constants[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"{where}.{k} = {v!r} is invalid: allowed a number")
            check_constant(model, k, float(v), f"{where}.{k}")
            vals[k] = float(v)
        return Material(key, model, tuple(vals.items()))

    def as_dict(self) -> dict[str, float]:
        return dict(self.constants)

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, **self.as_dict()}


@functools.lru_cache(maxsize=1)
def library_table() -> dict:
    """The package's materials.toml as a dict (constants with their sources)."""
    text = resources.files("jaxmpm").joinpath("data/materials.toml").read_text()
    return tomllib.loads(text)


def known_keys() -> tuple[str, ...]:
    """The material keys of the library, sorted."""
    return tuple(sorted(library_table()))


def library_material(key: str) -> Material:
    """The elastic Material of a library key (see module docstring)."""
    table = library_table()
    if key not in table:
        raise ValueError(f"material key {key!r} is unknown: known keys are {list(known_keys())}")
    entry = table[key]
    eos = entry["eos"]
    rho0 = float(eos["rho0"])
    if "elastic" in entry:
        el = entry["elastic"]
        return Material.make(key, "hypoelastic", rho0=rho0, E=float(el["E"]), nu=float(el["nu"]))
    model = eos["model"]
    if model == "ideal_gas":
        K = eos["gamma"] * eos["p0"]
    elif model == "stiffened_gas":
        K = eos["gamma"] * (eos["p0"] + eos["p_inf"])
    else:
        K = eos["K"]
    return Material.make(key, "linear_fluid", rho0=rho0, K=float(K))


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
