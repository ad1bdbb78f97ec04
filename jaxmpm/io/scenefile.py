"""Scene files (TOML) and built-in scenes: read, write, and `load_scene`.

A scene file has the top-level keys name, description, shape, transfer, energy_update, cfl,
t_end, axisymmetric and window (`Scene`'s fields of those names) and the tables [grid] (cells, h,
origin), [boundary] (x_lo ... z_hi: "free", "slip", "separating" or "fixed"; layers), [effects] (gravity,
gravity_ramp, damping, body_force, drag, drag_length, linear_drag, drag_heating,
interface_forces, continuity, c_h, fragmentation, artificial_viscosity, density_diffusion,
ambient_pressure), [output] (n_out),
[materials.<key>] and [[phase]] (name, material, geometry, velocity, field, ppc, fraction).
Unknown keys are errors, never ignored; every error is a ValueError naming the field (and the
line, for malformed TOML).

    name = "block_on_floor"
    shape = "ddmp"
    t_end = 1e-3
    [grid]
    cells = [40, 20]
    h = 0.01
    [boundary]
    y_lo = "fixed"
    [effects]
    gravity = [0.0, -9.81]
    [materials.soft]
    model = "linear_elastic"
    rho0 = 1000.0
    E = 1e6
    nu = 0.3
    [materials.plate]
    library = "al2024"          # a library key (`jaxmpm materials`), its default model,
    model = "hypoelastic"       # or another model kind; further keys override constants
    [[phase]]
    name = "block"
    material = "soft"
    velocity = [1.0, 0.0]
    geometry = { type = "box", lo = [0.1, 0.0], hi = [0.2, 0.1] }

A geometry is { type = "box", lo, hi }, { type = "sphere", center, radius } or
{ type = "difference", base = <box or sphere>, minus = [<geometries>] } (the base outside the others).
"""

# longer than 400 lines on purpose: the scene file's whole format, read (scene_from_dict) and written
# (scene_to_dict, scene_to_toml) in one place, so that the two stay each other's inverse

from __future__ import annotations

import json
import os
from typing import Any, Mapping

from jaxmpm.materials import Material, known_keys, library_material
from jaxmpm.materials.models import model_names
from jaxmpm.model.scene import DENSITY_DIFFUSION, Boundary, Grid, Phase, Scene, geometry_from_dict
from jaxmpm.scenes import BUILTINS
from jaxmpm.scenes.options import builder_options

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

TOP_KEYS = (
    "name",
    "description",
    "shape",
    "transfer",
    "energy_update",
    "cfl",
    "t_end",
    "axisymmetric",
    "window",
    "grid",
    "boundary",
    "effects",
    "output",
    "materials",
    "phase",
)
GRID_KEYS = ("cells", "h", "origin")
EFFECT_KEYS = (
    "gravity",
    "gravity_ramp",
    "damping",
    "body_force",
    "drag",
    "drag_length",
    "linear_drag",
    "drag_heating",
    "interface_forces",
    "continuity",
    "c_h",
    "fragmentation",
    "artificial_viscosity",
    "density_diffusion",
    "ambient_pressure",
)
OUTPUT_KEYS = ("n_out",)
PHASE_KEYS = ("name", "material", "geometry", "velocity", "field", "ppc", "fraction")


def _check_keys(d: Any, allowed, where: str) -> dict:
    if not isinstance(d, Mapping):
        raise ValueError(f"{where} = {d!r} is invalid: allowed a table with keys {list(allowed)}")
    for k in d:
        if k not in allowed:
            raise ValueError(
                f"{where}.{k} is an unknown key: allowed keys are {list(allowed)}"
                if where
                else f"{k} is an unknown key: allowed top-level keys are {list(allowed)}"
            )
    return dict(d)


def _typed(value, types, where, allowed):
    if isinstance(value, bool) and bool not in types:
        raise ValueError(f"{where} = {value!r} is invalid: allowed {allowed}")
    if not isinstance(value, types):
        raise ValueError(f"{where} = {value!r} is invalid: allowed {allowed}")
    return value


def scene_from_dict(d: Mapping) -> Scene:
    """Build a Scene from the dict form of a scene file. ValueError names the field on bad input."""
    # longer than 60 lines on purpose: one section of the scene file after another, each read and checked where
    # it is met
    d = _check_keys(d, TOP_KEYS, "")
    if "grid" not in d:
        raise ValueError("grid is missing: a scene needs a [grid] table with cells and h")
    grid_table = _check_keys(d["grid"], GRID_KEYS, "grid")
    if "cells" not in grid_table or "h" not in grid_table:
        raise ValueError(f"grid.{'cells' if 'cells' not in grid_table else 'h'} is missing: [grid] needs cells and h")
    cells = grid_table["cells"]
    if isinstance(cells, list):
        cells = tuple(cells)
    grid = Grid(cells=cells, h=grid_table["h"], origin=grid_table.get("origin"))

    b = _check_keys(
        d.get("boundary", {}), ("layers",) + tuple(f"{a}_{s}" for a in "xyz" for s in ("lo", "hi")), "boundary"
    )
    layers = b.pop("layers", 1)
    boundary = Boundary(faces=tuple((k, v) for k, v in b.items()), layers=layers)

    e = _check_keys(d.get("effects", {}), EFFECT_KEYS, "effects")
    o = _check_keys(d.get("output", {}), OUTPUT_KEYS, "output")

    mats = []
    m_all = d.get("materials", {})
    if not isinstance(m_all, Mapping):
        raise ValueError(f"materials = {m_all!r} is invalid: allowed tables [materials.<key>]")
    for key, spec in m_all.items():
        if not isinstance(spec, Mapping):
            raise ValueError(f"materials.{key} = {spec!r} is invalid: allowed a table with model and constants")
        spec = dict(spec)
        if "library" in spec:
            lib = _typed(spec.pop("library"), (str,), f"materials.{key}.library", "a library material key")
            if lib not in known_keys():
                raise ValueError(f"materials.{key}.library = {lib!r} is invalid: allowed one of {list(known_keys())}")
            model = (
                _typed(spec.pop("model"), (str,), f"materials.{key}.model", "a model name") if "model" in spec else None
            )
            mats.append(library_material(lib, model, key, **spec))
            continue
        if "model" not in spec:
            raise ValueError(
                f"materials.{key}.model is missing: allowed {model_names()} "
                f"(or library = '<key>' with one of {list(known_keys())})"
            )
        model = _typed(spec.pop("model"), (str,), f"materials.{key}.model", "a model name")
        mats.append(Material.make(key, model, **spec))

    phases = d.get("phase", [])
    if isinstance(phases, Mapping):
        raise ValueError("phase is a single table [phase]: allowed an array of tables, each written [[phase]]")
    if not isinstance(phases, list) or not phases:
        raise ValueError("phase is missing: a scene needs at least one [[phase]] table")
    plist = []
    for i, p in enumerate(phases):
        where = f"phase[{i}]"
        p = _check_keys(p, PHASE_KEYS, where)
        for k in ("name", "material", "geometry"):
            if k not in p:
                raise ValueError(f"{where}.{k} is missing: a phase needs name, material and geometry")
        name = _typed(p["name"], (str,), f"{where}.name", "a string")
        where = f"phase.{name}"
        plist.append(
            Phase(
                name=name,
                material=_typed(p["material"], (str,), f"{where}.material", "a material key (string)"),
                geometry=geometry_from_dict(p["geometry"], f"{where}.geometry"),
                velocity=tuple(p["velocity"]) if isinstance(p.get("velocity"), list) else p.get("velocity"),
                field=p.get("field", 0),
                ppc=p.get("ppc", 2),
                fraction=p.get("fraction", 1.0),
            )
        )

    kw = {}
    for k, types, allowed in (
        ("name", (str,), "a string"),
        ("description", (str,), "a string"),
        ("shape", (str,), "ddmp | linear | bspline2"),
        ("transfer", (str,), "musl | seed | seed_halfstep | apic"),
        ("energy_update", (str,), "midpoint | compatible"),
        ("cfl", (int, float), "a number in (0, 1]"),
        ("t_end", (int, float), "a number > 0 s"),
        ("axisymmetric", (bool,), "true | false"),
    ):
        if k in d:
            kw[k] = _typed(d[k], types, k, allowed)
    if "window" in d:
        w = _typed(d["window"], (list,), "window", "a list of cells per axis")
        kw["window"] = tuple(w)
    if "artificial_viscosity" in e:
        av = e["artificial_viscosity"]
        kw["artificial_viscosity"] = tuple(av) if isinstance(av, list) else av
    if "gravity" in e:
        grav = e["gravity"]
        kw["gravity"] = tuple(grav) if isinstance(grav, list) else grav
    for k in (
        "gravity_ramp",
        "damping",
        "drag",
        "drag_length",
        "linear_drag",
        "c_h",
        "density_diffusion",
        "ambient_pressure",
    ):
        if k in e:
            kw[k] = _typed(e[k], (int, float), f"effects.{k}", "a number")
    if "fragmentation" in e:
        kw["fragmentation"] = _typed(
            e["fragmentation"], (str,), "effects.fragmentation", "'failed' | 'plastic' | 'tensile'"
        )
    if "continuity" in e:
        kw["continuity"] = _typed(e["continuity"], (str,), "effects.continuity", "'auto' | 'off' | 'transport'")
    if "body_force" in e:
        kw["body_force"] = _typed(e["body_force"], (bool,), "effects.body_force", "true | false")
    if "drag_heating" in e:
        kw["drag_heating"] = _typed(e["drag_heating"], (bool,), "effects.drag_heating", "true | false")
    if "interface_forces" in e:
        f = _typed(
            e["interface_forces"], (bool, list), "effects.interface_forces", "true | false | a list of velocity fields"
        )
        kw["interface_forces"] = tuple(f) if isinstance(f, list) else f
    if "n_out" in o:
        kw["n_out"] = o["n_out"]
    return Scene(grid=grid, phases=tuple(plist), materials=tuple(mats), boundary=boundary, **kw)


def scene_to_dict(scene: Scene) -> dict:
    """The dict form of a scene file (inverse of scene_from_dict)."""
    d = {
        "name": scene.name,
        "description": scene.description,
        "shape": scene.shape,
        "transfer": scene.transfer,
        "cfl": scene.cfl,
        "t_end": scene.t_end,
        "grid": scene.grid.to_dict(),
    }
    if scene.energy_update != "midpoint":
        d["energy_update"] = scene.energy_update
    if scene.axisymmetric:
        d["axisymmetric"] = True
    if scene.window is not None:
        d["window"] = list(scene.window)
    b = dict(scene.boundary.faces)
    if scene.boundary.layers != 1:
        b["layers"] = scene.boundary.layers
    d["boundary"] = b
    e = {}
    if scene.gravity is not None:
        e["gravity"] = list(scene.gravity)
        e["gravity_ramp"] = scene.gravity_ramp
    if scene.damping is not None:
        e["damping"] = scene.damping
    if scene.body_force:
        e["body_force"] = True
    for k in ("drag", "drag_length", "linear_drag", "c_h", "ambient_pressure"):
        if getattr(scene, k) is not None:
            e[k] = getattr(scene, k)
    if scene.drag_heating:
        e["drag_heating"] = True
    if scene.interface_forces is not True:
        e["interface_forces"] = list(scene.interface_forces) if scene.interface_forces else False
    if scene.continuity != "auto":
        e["continuity"] = scene.continuity
    if scene.has_closure and scene.fragmentation != "failed":
        e["fragmentation"] = scene.fragmentation
    if scene.artificial_viscosity is not None:
        e["artificial_viscosity"] = list(scene.artificial_viscosity)
    if scene.density_diffusion != DENSITY_DIFFUSION:
        e["density_diffusion"] = scene.density_diffusion
    d["effects"] = e
    d["output"] = {"n_out": scene.n_out}
    used = {p.material.key if isinstance(p.material, Material) else p.material for p in scene.phases}
    mats = {m.key: m.to_dict() for m in scene.materials}
    for p in scene.phases:  # inline Material objects become scene materials
        if isinstance(p.material, Material) and p.material.key not in mats:
            mats[p.material.key] = p.material.to_dict()
    d["materials"] = {k: v for k, v in mats.items() if k in used}
    d["phase"] = [p.to_dict() for p in scene.phases]
    return d


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(a) for a in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml_value(a)}" for k, a in v.items()) + " }"
    raise TypeError(f"cannot write {v!r} to TOML")


def scene_to_toml(scene: Scene) -> str:
    """TOML text of the scene; `load_scene` of this text gives back an equal Scene (a Phase that
    holds a Material object comes back naming it by key, with the Material among the scene's
    materials: an equivalent Scene, not an equal one)."""
    d = scene_to_dict(scene)
    lines = [
        f"{k} = {_toml_value(d[k])}"
        for k in ("name", "description", "shape", "transfer", "energy_update", "cfl", "t_end", "axisymmetric", "window")
        if k in d
    ]
    for table in ("grid", "boundary", "effects", "output"):
        lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in d[table].items()]
    for key, spec in d["materials"].items():
        lines += ["", f"[materials.{key}]"] + [f"{k} = {_toml_value(v)}" for k, v in spec.items()]
    for p in d["phase"]:
        lines += ["", "[[phase]]"] + [f"{k} = {_toml_value(v)}" for k, v in p.items()]
    return "\n".join(lines) + "\n"


def parse_toml(text: str, source: str = "<string>") -> dict:
    """TOML text -> dict; ValueError naming `source` and the line on malformed TOML."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{source}: malformed TOML: {e}") from None


def scene_from_toml(text: str, source: str = "<string>") -> Scene:
    """A Scene from scene-file text (see the module docstring for the keys)."""
    return scene_from_dict(parse_toml(text, source))


def set_dotted(d: dict, key: str, value: Any) -> None:
    """Set `key` = value in the dict form of a scene: 'grid.cells', 'effects.gravity',
    'phase.<name>.velocity', 'materials.<key>.E', 't_end'."""
    parts = key.split(".")
    node = d
    i = 0
    while i < len(parts) - 1:
        p = parts[i]
        if p == "phase" and isinstance(node.get("phase"), list):
            name = parts[i + 1]
            match = [ph for ph in node["phase"] if ph.get("name") == name]
            if not match:
                raise ValueError(
                    f"--set {key}: no phase named {name!r} (phases: {[ph.get('name') for ph in node['phase']]})"
                )
            node = match[0]
            i += 2
            continue
        if (
            p == "materials"
            and i == 0
            and parts[1] not in node.get("materials", {})
            and parts[-1] not in ("model", "library")
        ):
            raise ValueError(
                f"--set {key}: no material named {parts[1]!r} (materials: {sorted(node.get('materials', {}))}; "
                "a new one needs its model or library first)"
            )
        if p not in node:
            node[p] = {}
        if not isinstance(node[p], dict):
            raise ValueError(f"--set {key}: {p!r} is not a table")
        node = node[p]
        i += 1
    node[parts[-1]] = value


def parse_value(text: str) -> Any:
    """A --set value as TOML would read it (number, string, list, bool); bare words are strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _builder_options(name, build, options) -> dict:
    """options, checked against the built-in scene's builder: ValueError naming an unknown one and
    listing those the builder takes (`jaxmpm scenes` shows them with their defaults)."""
    allowed = list(builder_options(build))
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"{name}: option(s) {unknown} are unknown: allowed {allowed}")
    return options


def load_scene(name_or_path: str | os.PathLike, *, overrides: Mapping[str, Any] | None = None, **options: Any) -> Scene:
    """A built-in scene by name (options are passed to its builder, e.g. resolution=0.5), or a
    scene file (.toml path). overrides: {'dotted.key': value} applied to the scene's dict form."""
    path = os.fspath(name_or_path)
    if path.endswith(".toml") or os.path.sep in path:
        if options:
            raise ValueError(f"options {sorted(options)} apply to built-in scenes only; edit the file {path!r} instead")
        if os.path.isdir(path):
            raise ValueError(f"scene file {path!r} is a folder: allowed a .toml scene file or a built-in scene name")
        if not os.path.isfile(path):
            raise ValueError(f"scene file {path!r} does not exist")
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except UnicodeDecodeError as e:
            raise ValueError(
                f"scene file {path!r} is not a TOML scene file: it is not UTF-8 text (byte {e.start}: {e.reason})"
            ) from None
        d = parse_toml(text, path)
        source = f"{path}: "  # errors in the file's contents name it
    elif path in BUILTINS:
        scene = BUILTINS[path].build(**_builder_options(path, BUILTINS[path].build, options))
        if not overrides:
            return scene
        d = scene_to_dict(scene)
        source = ""
    else:
        raise ValueError(
            f"scene {path!r} is neither a built-in scene nor a .toml file: built-ins are {sorted(BUILTINS)}"
        )
    if overrides is not None and not isinstance(overrides, Mapping):
        raise ValueError(
            f"overrides = {overrides!r} is invalid: allowed a mapping {{'dotted.key': value}}, "
            "e.g. {'grid.cells': [32, 32]}"
        )
    for k, v in (overrides or {}).items():
        set_dotted(d, k, v)
    try:
        return scene_from_dict(d)
    except ValueError as e:
        raise ValueError(f"{source}{e}") from None
