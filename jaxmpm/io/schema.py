"""What an output file holds: the State's fields, their SI units and shapes, and the checks that a
scene and its arrays are what `write` and `plot_state` expect."""

from __future__ import annotations

from jaxmpm.model.scene import Scene
from jaxmpm.model.state import phase_slices

UNITS = {
    "x": "m",
    "v": "m/s",
    "volume": "m^3",
    "mass": "kg",
    "F": "1",
    "stress": "Pa",
    "energy": "J/kg",
    "C": "1/s",
    "eps_ps": "1",
    "damage": "1",
    "pressure": "Pa",
}


FIELDS = ("x", "v", "volume", "mass", "F", "stress", "energy")


OPTIONAL = ("C", "eps_ps", "pressure", "damage")


def units(name: str, dim: int, axisymmetric: bool = False) -> str:
    """SI units of a dataset, or of a total ('kinetic', 'internal', 'total_energy': J). Volumes,
    masses and energy totals are per unit depth in 2D (plane strain: m^2, kg/m, J/m), per radian
    in axisymmetric scenes (m^3/rad, kg/rad, J/rad) and per unit cross-section area in 1D
    (m, kg/m^2, J/m^2), as in the State."""
    if axisymmetric and name in ("kinetic", "internal", "total_energy", "volume", "mass"):
        return {"volume": "m^3/rad", "mass": "kg/rad"}.get(name, "J/rad")
    if name in ("kinetic", "internal", "total_energy"):
        return {1: "J/m^2", 2: "J/m", 3: "J"}[dim]
    if name == "volume":
        return {1: "m", 2: "m^2", 3: "m^3"}[dim]
    if name == "mass":
        return {1: "kg/m^2", 2: "kg/m", 3: "kg"}[dim]
    return UNITS[name]


def check_scene(scene: object) -> None:
    """ValueError unless `scene` is a jaxmpm.Scene."""
    if not isinstance(scene, Scene):
        raise ValueError(f"scene = {type(scene).__name__} is invalid: allowed a jaxmpm.Scene")


def field_shapes(scene: Scene) -> dict:
    """{field: shape} of one State of `scene` (no time axis): x, v (n, d); mass, volume, energy,
    eps_ps, pressure, damage (n,); F, stress (n, md, md) with md = scene.material_dim; C (n, d, d)."""
    n, d, md = phase_slices(scene)[-1].stop, scene.dim, scene.material_dim
    return {
        "x": (n, d),
        "v": (n, d),
        "volume": (n,),
        "mass": (n,),
        "F": (n, md, md),
        "stress": (n, md, md),
        "energy": (n,),
        "C": (n, d, d),
        "eps_ps": (n,),
        "pressure": (n,),
        "damage": (n,),
    }


def check_shapes(scene: Scene, fields: dict, what: str, lead: tuple = ()) -> None:
    """ValueError naming the first field of `fields` ({name: array}) whose shape is not the scene's
    (with the leading axes `lead`, e.g. (n_times,)), or that is not a floating-point array."""
    n = phase_slices(scene)[-1].stop
    for name, shape in field_shapes(scene).items():
        if name not in fields:
            continue
        a = fields[name]
        need = lead + shape
        if tuple(a.shape) != need:
            raise ValueError(
                f"{what}.{name} has shape {tuple(a.shape)}: the scene {scene.name!r} has {n} particles "
                f"in {scene.dim}D and needs {need}"
            )
        if a.dtype.kind != "f":
            raise ValueError(f"{what}.{name} has dtype {a.dtype}: allowed floating-point numbers")
