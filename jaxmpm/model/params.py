"""Params: the numbers of the model, a pytree of arrays (traced, differentiable, vmap-able).

    params.phases[phase_name][constant]   material constants of each phase (SI; see Material)
    params.body_force[phase_name]         (d,) m/s^2 body acceleration (only if scene.body_force)
    params.gravity, gravity_ramp, damping, cfl, drag, drag_length, linear_drag, c_h,
    artificial_viscosity, ambient_pressure
                                          the numbers of the scene's effects: their units, allowed
                                          ranges and defaults are the table of jaxmpm.model.numbers
                                          (gravity and body_force are (d,), artificial_viscosity is
                                          (2,) = (c_linear, c_quadratic), the others are numbers)

Each number has the name of the Scene field (and scene-file key) it comes from: `params.drag` is
C_d of (E3), `scene.drag`'s value. Edit with `dataclasses.replace` or `Params.with_constant`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike, DTypeLike

from jaxmpm.materials.models import check_constant, model_of
from jaxmpm.model.numbers import BY_NAME, NUMBERS, OLD_NAMES, Number, warn_old_name
from jaxmpm.model.scene import Scene

_NUMBER_NAMES = tuple(n.name for n in NUMBERS)
# the pytree's order of leaves (that of the versions before the table)
FIELDS = ("phases", *_NUMBER_NAMES[:3], "body_force", *_NUMBER_NAMES[3:])


@dataclass(frozen=True, init=False)
class Params:
    """The model's numbers (a pytree; the fields and their units are in the module docstring).

    Built with keywords, one per field; the old names drag_coefficient, av_linear and av_quadratic
    are accepted for one release with a DeprecationWarning (and read back as properties)."""

    phases: dict
    gravity: jax.Array
    gravity_ramp: jax.Array
    damping: jax.Array
    body_force: dict
    cfl: jax.Array
    drag: jax.Array
    drag_length: jax.Array
    linear_drag: jax.Array
    c_h: jax.Array
    artificial_viscosity: jax.Array
    ambient_pressure: jax.Array

    def __init__(self, **fields):
        for old in [k for k in fields if k in OLD_NAMES]:
            warn_old_name(old)
            new, index = OLD_NAMES[old]
            value = fields.pop(old)
            if index is None:
                fields[new] = value
            else:  # one entry of a pair: the other entry is kept
                pair = fields[new]
                parts = [pair[..., 0], pair[..., 1]]
                parts[index] = jnp.asarray(value, dtype=jnp.result_type(pair))
                fields[new] = jnp.stack(parts, axis=-1)
        unknown = sorted(set(fields) - set(FIELDS))
        missing = [k for k in FIELDS if k not in fields]
        if unknown or missing:
            raise TypeError(
                f"Params({', '.join(unknown or missing)}) is invalid: allowed the fields {list(FIELDS)} "
                "(jaxmpm.default_params(scene) builds them)"
            )
        for k in FIELDS:
            object.__setattr__(self, k, fields[k])

    @property
    def drag_coefficient(self) -> jax.Array:
        """Deprecated: `drag`."""
        warn_old_name("drag_coefficient")
        return self.drag

    @property
    def av_linear(self) -> jax.Array:
        """Deprecated: `artificial_viscosity[0]`."""
        warn_old_name("av_linear")
        return self.artificial_viscosity[..., 0]

    @property
    def av_quadratic(self) -> jax.Array:
        """Deprecated: `artificial_viscosity[1]`."""
        warn_old_name("av_quadratic")
        return self.artificial_viscosity[..., 1]

    def with_constant(self, phase: str, name: str, value: ArrayLike) -> "Params":
        """A copy with `params.phases[phase][name] = value`."""
        if phase not in self.phases:
            raise ValueError(f"params.phases[{phase!r}] is unknown: phases are {list(self.phases)}")
        if name not in self.phases[phase]:
            raise ValueError(f"params.phases[{phase!r}][{name!r}] is unknown: constants are {list(self.phases[phase])}")
        phases = {k: dict(v) for k, v in self.phases.items()}
        try:
            phases[phase][name] = jnp.asarray(value, dtype=jnp.result_type(self.phases[phase][name]))
        except (TypeError, ValueError):
            raise ValueError(f"params.phases[{phase!r}][{name!r}] = {value!r} is invalid: allowed a number") from None
        return dataclasses.replace(self, phases=phases)


jax.tree_util.register_dataclass(Params, data_fields=list(FIELDS), meta_fields=[])


def check_dtype(dtype: DTypeLike) -> None:
    """float32, or float64 where jax_enable_x64 is on: else a ValueError naming the allowed ones."""
    allowed = ("float32", "float64") if jax.config.jax_enable_x64 else ("float32",)
    try:
        name = np.dtype(dtype).name
    except TypeError:
        name = repr(dtype)
    if name not in allowed:
        raise ValueError(
            f"dtype = {name} is invalid: allowed {' or '.join(allowed)}"
            + ("" if jax.config.jax_enable_x64 else " (float64 after jax.config.update('jax_enable_x64', True))")
        )


def scene_number(scene: Scene, number: Number) -> float | tuple[float, ...]:
    """The value `default_params` gives one number of the table: the scene's, or the table's
    default where the scene's effect is off."""
    value = getattr(scene, number.scene_attribute)
    if number.switch_attribute and getattr(scene, number.switch_attribute) is None:
        value = None
    return off_value(scene, number) if value is None else value


def off_value(scene: Scene, number: Number) -> float | np.ndarray:
    """The table's default of a number (the value Params holds where the scene's effect is off)."""
    if number.default == "h":
        return scene.grid.h
    if number.size == 0:
        return number.default
    return np.full(scene.dim if number.size == "d" else number.size, float(number.default))


def default_params(scene: Scene, dtype: np.dtype | type | None = None) -> Params:
    """Params holding the scene's numbers. dtype: float64 when jax_enable_x64 is on, else float32
    (the two allowed; float64 needs jax_enable_x64)."""
    if not isinstance(scene, Scene):
        raise TypeError(
            f"scene = {scene!r} is invalid: allowed a Scene (jaxmpm.load_scene(name) builds a built-in one)"
        )
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    check_dtype(dtype)
    as_array = lambda v: jnp.asarray(v, dtype=dtype)
    phases = {p.name: {k: as_array(v) for k, v in scene.material(p).constants} for p in scene.phases}
    return Params(
        phases=phases,
        body_force={p.name: as_array(np.zeros(scene.dim)) for p in scene.phases},
        **{n.name: as_array(scene_number(scene, n)) for n in NUMBERS},
    )


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _check_shapes(params: Params) -> None:
    """One run's Params hold numbers where the table has numbers (the vectors are checked with
    their values); an ensemble's batch is checked member by member."""
    leaves = [(f"params.phases[{p!r}][{k!r}]", v) for p, c in params.phases.items() for k, v in c.items()]
    leaves += [(f"params.{n.name}", getattr(params, n.name)) for n in NUMBERS if n.size == 0]
    for name, value in leaves:
        if _is_concrete(value) and np.shape(value) != ():
            raise ValueError(
                f"{name} has shape {np.shape(value)}: allowed a number "
                "(one run's Params; an ensemble takes a batch of them, jaxmpm.batch.sweep / stack)"
            )


def _check_phases(scene: Scene, params: Params) -> None:
    """Params has the scene's phases, in its constants and in its body forces."""
    names = scene.phase_names()
    if set(params.phases) != set(names):
        raise ValueError(f"params.phases has phases {sorted(params.phases)}: the scene has {sorted(names)}")
    if set(params.body_force) != set(names):
        raise ValueError(f"params.body_force has phases {sorted(params.body_force)}: the scene has {sorted(names)}")


def _check_constants(scene: Scene, params: Params) -> None:
    """Each phase has the constants of its model, each in the model's range."""
    for p in scene.phases:
        model = scene.material(p).model
        missing = sorted(set(model_of(model).constants) - set(params.phases[p.name]))
        if missing:
            raise ValueError(
                f"params.phases[{p.name!r}][{missing[0]!r}] is missing: model {model!r} needs "
                f"{sorted(model_of(model).constants)}"
            )
        for k, v in params.phases[p.name].items():
            if k not in model_of(model).constants:
                raise ValueError(f"params.phases[{p.name!r}][{k!r}] is not a constant of model {model!r}")
            if _is_concrete(v):
                for x in np.atleast_1d(np.asarray(v, dtype=float)):
                    check_constant(model, k, float(x), f"params.phases[{p.name!r}][{k!r}]")


def _check_numbers(scene: Scene, params: Params) -> None:
    """Every number of the table in its range (NUMBERS), and each body force like gravity."""
    for n in NUMBERS:
        value = getattr(params, n.name)
        if _is_concrete(value):
            n.check_params_value(value, scene.dim)
    gravity = BY_NAME["gravity"]
    for k, b in params.body_force.items():
        if _is_concrete(b):
            gravity.check_params_value(b, scene.dim, label=f"body_force[{k!r}]")


def _check_unused(scene: Scene, params: Params) -> None:
    """A number whose effect the scene lacks keeps its default: another value would change nothing
    (e.g. a sweep of C_h in a scene without the closure)."""
    for n in NUMBERS:
        value = getattr(params, n.name)
        if not n.switch_attribute or getattr(scene, n.switch_attribute) is not None or not _is_concrete(value):
            continue
        if not np.allclose(np.asarray(value, dtype=float), off_value(scene, n), rtol=1e-6, atol=0.0):
            raise ValueError(f"params.{n.name} (the scene has no {n.off}): set it in the scene to switch the effect on")
    if not scene.body_force and any(_is_concrete(b) and np.any(np.asarray(b) != 0) for b in params.body_force.values()):
        raise ValueError(
            "params.body_force (the scene has body_force = false): set it in the scene to switch the effect on"
        )


def check_params(scene: Scene, params: Params) -> None:
    """Raise ValueError naming the field if a concrete Param is out of range or does not fit the
    scene. Traced values (under jit/grad/vmap) are skipped: this is a host-side check."""
    if not isinstance(params, Params):
        raise ValueError(f"params = {type(params).__name__} is invalid: allowed a jaxmpm.Params")
    _check_phases(scene, params)
    _check_shapes(params)
    _check_constants(scene, params)
    _check_numbers(scene, params)
    _check_unused(scene, params)
