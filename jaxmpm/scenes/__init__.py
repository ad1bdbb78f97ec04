"""Built-in scenes. Each builder takes keyword options (e.g. `resolution`) and returns a Scene;
its docstring states the source, geometry, phases, effects and what it measures."""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Callable

from jaxmpm.model.params import Params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, init_state
from jaxmpm.scenes import basic, impact, penetration, taylor
from jaxmpm.scenes.options import builder_options


@dataclass(frozen=True)
class Builtin:
    build: Callable
    summary: str
    prepare: Callable | None = (
        None  # prepare(scene, params, state) -> state: initial fields a scene file cannot express
    )
    ranges: Callable | None = (
        None  # ranges(**options) -> {option: options.Range}: the allowed values the builder checks
    )


BUILTINS = {
    "elastic_impact": Builtin(
        basic.elastic_impact,
        "two elastic disks collide head-on (2D plane strain; the default scene)",
        ranges=basic.elastic_impact_ranges,
    ),
    "vibrating_bar": Builtin(
        basic.vibrating_bar,
        "1D fixed-free elastic bar in its first mode (exact solution; Bardenhagen 2002)",
        basic.vibrating_bar_state,
        basic.vibrating_bar_ranges,
    ),
    "self_weight_column": Builtin(
        basic.self_weight_column,
        "1D soft column settling under its own weight (exact static stress; cell crossing)",
        ranges=basic.self_weight_column_ranges,
    ),
    "mpm88": Builtin(
        basic.mpm88,
        "the peers' benchmark: 2D weakly compressible fluid, B-spline APIC, 128^2 grid",
        ranges=basic.mpm88_ranges,
    ),
    "debris_cloud": Builtin(
        impact.debris_cloud,
        "Al-2024 sphere on an Al-2024 plate at 6.71 km/s (2D axisymmetric; partly validated)",
        ranges=impact.debris_cloud_ranges,
    ),
    "taylor_bar": Builtin(
        taylor.taylor_bar,
        "OFHC copper rod on a rigid wall at 190 m/s (2D axisymmetric; Johnson & Cook 1983; "
        "--opt material=steel_42crmo4 | copper_bilinear: the Johnson-Cook steel and "
        "bilinear copper verification cases)",
        ranges=taylor.taylor_bar_ranges,
    ),
    "taylor_brittle": Builtin(
        taylor.taylor_brittle,
        "brittle (Maxwell, damage) rod on a rigid wall at 20 m/s: cracks (2D axisymmetric)",
        ranges=taylor.taylor_brittle_ranges,
    ),
    "projectile_concrete": Builtin(
        penetration.projectile_concrete,
        "steel projectile through water (or air: --opt fluid=air) into concrete at 500 m/s (2D axisymmetric)",
        ranges=penetration.projectile_concrete_ranges,
    ),
    "sandwich_target": Builtin(
        penetration.sandwich_target,
        "tungsten rod into a steel / CFRP laminate / steel sandwich at 800 m/s (2D axisymmetric)",
        ranges=penetration.sandwich_target_ranges,
    ),
    "rod_penetration": Builtin(
        penetration.rod_penetration,
        "tungsten-alloy L/D = 10 rod into semi-infinite steel at 2 km/s (2D axisymmetric; Tate check)",
        ranges=penetration.rod_penetration_ranges,
    ),
}

DEFAULT_SCENE = "elastic_impact"


def initial_state(scene: Scene, params: Params) -> State:
    """`jaxmpm.init_state`, then the built-in scene's own initial fields (e.g. the vibrating bar's
    mode shape) when the scene is that built-in: named like it and with its bodies (each phase's
    name, material and geometry as its builder makes them, whatever its options). A scene of
    one's own that carries a built-in's name keeps the initial state its file describes."""
    state = init_state(scene, params)
    b = BUILTINS.get(scene.name)
    if b is None or b.prepare is None or _bodies(scene) != _bodies(b.build()):
        return state
    return b.prepare(scene, params, state)


def _bodies(scene):
    return [(p.name, p.material, p.geometry) for p in scene.phases]


def describe(name: str) -> list[tuple[str, Any, str]]:
    """[(option, default, allowed values in words)] of the built-in scene `name`; floors that depend
    on other options are given at those options' defaults."""
    b = BUILTINS[name]
    options = builder_options(b.build)
    defaults = {k: p.default for k, p in options.items() if p.default is not inspect.Parameter.empty}
    ranges = b.ranges(**defaults) if b.ranges is not None else {}
    return [(k, defaults.get(k), ranges[k].words if k in ranges else "see the builder's docstring") for k in options]
