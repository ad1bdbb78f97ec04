"""Params: the numbers of the model, a pytree of arrays (traced, differentiable, vmap-able).

    params.phases[phase_name][constant]   material constants of each phase (SI; see Material)
    params.gravity                        (d,) gravity acceleration, m/s^2 (read only if the scene has gravity)
    params.gravity_ramp                   () s, gravity ramp time (smooth ramp from 0; 0 = none)
    params.damping                        () 1/s, nodal mass-proportional damping (only if the scene has damping)
    params.body_force[phase_name]         (d,) m/s^2 body acceleration (only if scene.body_force)
    params.cfl                            () Courant number in (0, 1]
    params.drag_coefficient               () C_d of the exchange (E3), dimensionless (read only with scene.drag)
    params.drag_length                    () d of (E3), m (default: the cell size h)
    params.linear_drag                    () K_lin of the linear drag term, kg/(m^3 s) (only with scene.linear_drag)
    params.c_h                            () C_h of the closure (E5: alpha = 1 - tanh(eps_ps / C_h), times the damage D
                                          with scene.fragmentation = 'failed'; eps_ps accrued in tension
                                          with 'tensile'; only with scene.c_h)
    params.av_linear, params.av_quadratic () c_l, c_q of the artificial viscosity (only where scene.viscosity is not None)

Edit with `dataclasses.replace` or `Params.with_constant`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.materials.models import check_constant, model_of
from jaxmpm.model.scene import Scene


@dataclass(frozen=True)
class Params:
    """The model's numbers (a pytree; the fields and their units are in the module docstring)."""

    phases: dict
    gravity: jax.Array
    gravity_ramp: jax.Array
    damping: jax.Array
    body_force: dict
    cfl: jax.Array
    drag_coefficient: jax.Array
    drag_length: jax.Array
    linear_drag: jax.Array
    c_h: jax.Array
    av_linear: jax.Array
    av_quadratic: jax.Array

    def with_constant(self, phase: str, name: str, value) -> "Params":
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


jax.tree_util.register_dataclass(
    Params,
    data_fields=[
        "phases",
        "gravity",
        "gravity_ramp",
        "damping",
        "body_force",
        "cfl",
        "drag_coefficient",
        "drag_length",
        "linear_drag",
        "c_h",
        "av_linear",
        "av_quadratic",
    ],
    meta_fields=[],
)


def default_params(scene, dtype=None) -> Params:
    """Params holding the scene's numbers. dtype: float64 when jax_enable_x64 is on, else float32
    (the two allowed; float64 needs jax_enable_x64)."""
    if not isinstance(scene, Scene):
        raise TypeError(
            f"scene = {scene!r} is invalid: allowed a Scene (jaxmpm.load_scene(name) builds a built-in one)"
        )
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
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
    f = lambda v: jnp.asarray(v, dtype=dtype)
    d = scene.dim
    phases = {p.name: {k: f(v) for k, v in scene.material(p).constants} for p in scene.phases}
    return Params(
        phases=phases,
        gravity=f(scene.gravity if scene.gravity is not None else np.zeros(d)),
        gravity_ramp=f(scene.gravity_ramp),
        damping=f(scene.damping if scene.damping is not None else 0.0),
        body_force={p.name: f(np.zeros(d)) for p in scene.phases},
        cfl=f(scene.cfl),
        drag_coefficient=f(scene.drag if scene.drag is not None else 0.0),
        drag_length=f(scene.drag_length if scene.drag_length is not None else scene.grid.h),
        linear_drag=f(scene.linear_drag if scene.linear_drag is not None else 0.0),
        c_h=f(scene.c_h if scene.has_closure else 1.0),
        av_linear=f(scene.viscosity[0] if scene.viscosity is not None else 0.0),
        av_quadratic=f(scene.viscosity[1] if scene.viscosity is not None else 0.0),
    )


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _check_shapes(params: Params, d: int) -> None:
    """One run's Params hold scalars (and (d,) vectors for gravity and the body forces, checked
    with their values); an ensemble's batch is checked member by member."""
    leaves = [(f"params.phases[{p!r}][{k!r}]", v, ()) for p, c in params.phases.items() for k, v in c.items()]
    leaves += [
        (f"params.{n}", getattr(params, n), ())
        for n in (
            "gravity_ramp",
            "damping",
            "cfl",
            "drag_coefficient",
            "drag_length",
            "linear_drag",
            "c_h",
            "av_linear",
            "av_quadratic",
        )
    ]
    for name, value, shape in leaves:
        if _is_concrete(value) and np.shape(value) != shape:
            raise ValueError(
                f"{name} has shape {np.shape(value)}: allowed a number "
                "(one run's Params; an ensemble takes a batch of them, jaxmpm.batch.sweep / stack)"
            )


def check_params(scene, params: Params) -> None:
    """Raise ValueError naming the field if a concrete Param is out of range or does not fit the
    scene. Traced values (under jit/grad/vmap) are skipped: this is a host-side check."""
    if not isinstance(params, Params):
        raise ValueError(f"params = {type(params).__name__} is invalid: allowed a jaxmpm.Params")
    names = scene.phase_names()
    if set(params.phases) != set(names):
        raise ValueError(f"params.phases has phases {sorted(params.phases)}: the scene has {sorted(names)}")
    d = scene.dim
    _check_shapes(params, d)
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
    if _is_concrete(params.cfl):
        for x in np.atleast_1d(np.asarray(params.cfl, dtype=float)):
            if not 0 < x <= 1:
                raise ValueError(f"params.cfl = {float(x)!r} is invalid: allowed (0, 1]")
    for name, value in (
        ("gravity", params.gravity),
        *((f"body_force[{k!r}]", b) for k, b in params.body_force.items()),
    ):
        if _is_concrete(value):
            a = np.asarray(value)
            if a.shape != (d,) or not np.all(np.isfinite(a)):
                raise ValueError(
                    f"params.{name} = {a.tolist()} is invalid: allowed {d} finite numbers (m/s^2, one per axis)"
                )
    if set(params.body_force) != set(scene.phase_names()):
        raise ValueError(
            f"params.body_force has phases {sorted(params.body_force)}: the scene has {sorted(scene.phase_names())}"
        )
    if _is_concrete(params.gravity_ramp):
        a = np.asarray(params.gravity_ramp)
        if np.any(a < 0) or not np.all(np.isfinite(a)):
            raise ValueError(f"params.gravity_ramp = {a} is invalid: allowed >= 0 s")
    unused = []
    if scene.gravity is None and _is_concrete(params.gravity) and np.any(np.asarray(params.gravity) != 0):
        unused.append("gravity (the scene has no gravity effect)")
    if scene.damping is None and _is_concrete(params.damping) and np.any(np.asarray(params.damping) != 0):
        unused.append("damping (the scene has no damping effect)")
    if not scene.body_force and any(_is_concrete(b) and np.any(np.asarray(b) != 0) for b in params.body_force.values()):
        unused.append("body_force (the scene has body_force = false)")
    if (
        scene.drag is None
        and _is_concrete(params.drag_coefficient)
        and np.any(np.asarray(params.drag_coefficient) != 0)
    ):
        unused.append("drag_coefficient (the scene has no drag)")
    if scene.linear_drag is None and _is_concrete(params.linear_drag) and np.any(np.asarray(params.linear_drag) != 0):
        unused.append("linear_drag (the scene has no linear drag)")
    # the numbers of the effects below are read only with their effect: a value other than the
    # placeholder default_params gives them (e.g. a sweep of C_h) would change nothing
    for name, off, placeholder, why in (
        ("c_h", not scene.has_closure, 1.0, "no closure (effects.c_h)"),
        ("drag_length", scene.drag is None, scene.grid.h, "no drag"),
        ("gravity_ramp", scene.gravity is None, 0.0, "no gravity effect"),
        ("av_linear", scene.viscosity is None, 0.0, "no artificial viscosity"),
        ("av_quadratic", scene.viscosity is None, 0.0, "no artificial viscosity"),
    ):
        val = getattr(params, name)
        if (
            off
            and _is_concrete(val)
            and not np.allclose(np.asarray(val, dtype=float), placeholder, rtol=1e-6, atol=0.0)
        ):
            unused.append(f"{name} (the scene has {why})")
    for name, positive in (
        ("drag_coefficient", False),
        ("drag_length", True),
        ("linear_drag", False),
        ("c_h", True),
        ("av_linear", False),
        ("av_quadratic", False),
    ):
        val = getattr(params, name)
        if _is_concrete(val):
            a = np.asarray(val)
            if np.any(a < 0) or (positive and np.any(a <= 0)) or not np.all(np.isfinite(a)):
                raise ValueError(f"params.{name} = {a} is invalid: allowed {'> 0' if positive else '>= 0'}")
    if unused:
        raise ValueError(f"params.{unused[0]}: set it in the scene to switch the effect on")
    if _is_concrete(params.damping) and not np.all(np.isfinite(params.damping) & (np.asarray(params.damping) >= 0)):
        raise ValueError(f"params.damping = {params.damping} is invalid: allowed finite values >= 0 1/s")
