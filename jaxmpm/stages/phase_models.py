"""Each phase's material model evaluated on its particles: the phases grouped by model kind
(`model_groups`, `per_model`), the particle pressure, the bulk modulus and the wave speed. Used by
the closure, the grid stage and the constitutive update.

Shapes: N particles; SI units.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.materials.models import MODELS, model_of, split_model
from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.stages.layout import Layout


def fails(model_name: str) -> bool:
    """Whether a model kind has a failure part (a hydrocode composite with spall, Johnson-Cook
    failure, ...) or is a one-piece kind that sets damage (maxwell_brittle)."""
    if model_name in MODELS:
        return MODELS[model_name].can_fail
    return bool(split_model(model_name)[2])


def has_hydro(layout: Layout) -> bool:
    """Whether any phase's model is a hydrocode composition (an equation of state p(rho, e))."""
    return any(model_of(layout.scene.material(p).model).hydro for p in layout.scene.phases)


def pressure(layout: Layout, state: State) -> jax.Array:
    """(N,) pressure of every particle, Pa: state.pressure for the hydrocode models (EOS plus
    artificial viscosity), -tr(stress) / d for the total-stress models (so a user who edits the
    stress of such a State needs not edit the pressure)."""
    scene = layout.scene
    if all(model_of(scene.material(p).model).hydro for p in scene.phases):
        return state.pressure
    tr = -jnp.trace(state.stress, axis1=1, axis2=2) / state.stress.shape[-1]
    return jnp.concatenate(
        [
            state.pressure[sl] if model_of(scene.material(p).model).hydro else tr[sl]
            for p, sl in zip(scene.phases, layout.slices)
        ]
    )


def model_groups(layout: Layout) -> tuple[tuple[str, tuple[int, ...], slice | np.ndarray], ...]:
    """The phases grouped by model kind, in order of first appearance: a tuple of (model name,
    phase indices, particles) with particles a slice where the group's particles are contiguous
    in particle order, else a static index array. Static (from the scene)."""
    scene = layout.scene
    names = [scene.material(p).model for p in scene.phases]
    groups = []
    for name in dict.fromkeys(names):
        members = tuple(i for i, n in enumerate(names) if n == name)
        idx = np.concatenate([np.arange(layout.slices[i].start, layout.slices[i].stop) for i in members])
        contiguous = idx.size == 0 or np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size))
        groups.append((name, members, slice(int(idx[0]), int(idx[0]) + idx.size) if contiguous and idx.size else idx))
    return tuple(groups)


def per_model(layout: Layout, params: Params, fn: Callable[..., Any], *arrays: jax.Array | None) -> Any:
    """fn(model, constants, *arrays) -> pytree of (n, ...) arrays, evaluated once per model kind
    on that kind's particles and assembled in particle order. arrays: (N, ...) per-particle
    inputs (or None, passed through). fn is written for scalar constants: for a kind shared by
    several phases, their constants become per-particle arrays and fn runs under jax.vmap with
    each particle as a batch of one.

    Why: on the CPU the per-particle updates are dozens of small kernels each, and their cost is
    mostly per kernel: two phases of one kind (a projectile and its target of the same metal, in
    separate velocity fields) ran every kernel twice on half the particles."""
    scene = layout.scene
    outs, order = [], []
    for name, members, part in model_groups(layout):
        if (part.stop - part.start if isinstance(part, slice) else part.size) == 0:
            continue
        model = model_of(name)
        args = [None if a is None else a[part] for a in arrays]
        if len(members) == 1:
            outs.append(fn(model, params.phases[scene.phases[members[0]].name], *args))
        else:
            sizes = [layout.slices[i].stop - layout.slices[i].start for i in members]
            consts = [params.phases[scene.phases[i].name] for i in members]
            c = {
                k: jnp.concatenate([jnp.broadcast_to(jnp.asarray(ci[k]), (n,)) for ci, n in zip(consts, sizes)])
                for k in consts[0]
                if all(k in ci for ci in consts)
            }  # the kind's constants: every phase has them
            present = [i for i, a in enumerate(args) if a is not None]

            def one(c, *xs, model=model, present=present, n_args=len(args)):  # noqa: B008 (bound at definition)
                full = [None] * n_args
                for i, x in zip(present, xs):
                    full[i] = x[None]
                return jax.tree.map(lambda y: y[0], fn(model, c, *full))

            outs.append(jax.vmap(one)(c, *(args[i] for i in present)))
        order.append(np.arange(part.start, part.stop) if isinstance(part, slice) else part)
    order = np.concatenate(order)
    joined = jax.tree.map(lambda *xs: jnp.concatenate(xs), *outs)
    if np.array_equal(order, np.arange(order.size)):
        return joined
    inverse = np.argsort(order)
    return jax.tree.map(lambda a: a[inverse], joined)


def bulk_modulus_and_wave_speed(layout: Layout, params: Params, state: State) -> tuple[jax.Array, jax.Array]:
    """(N,) bulk modulus K (Pa) and longitudinal wave speed c (m/s) at the particles' state.

    Failed material (damage D, 1 = failed) carries no shear, so its longitudinal speed loses the
    shear part: c^2 = K / rho + (1 - D)(c_model^2 - K / rho) for the hydrocode models, whose
    c_model^2 = K / rho + 4 G / (3 rho). Without it a failed particle expanded to 1e-4 of its
    density kept 4 G / (3 rho) ~ (500 km/s)^2 and the CFL step of the debris cloud collapsed."""
    rho = state.mass / state.volume
    dim = layout.scene.material_dim
    K, cw = per_model(
        layout,
        params,
        lambda m, c, r, e: (
            m.bulk_modulus(c, r, e, dim) * jnp.ones_like(r),
            m.wave_speed(c, r, e, dim) * jnp.ones_like(r),
        ),
        rho,
        state.energy,
    )
    hydro = np.concatenate(
        [
            np.full(sl.stop - sl.start, model_of(layout.scene.material(p).model).hydro, bool)
            for p, sl in zip(layout.scene.phases, layout.slices)
        ]
    )
    if hydro.any():
        cb2 = K / rho
        shear = jnp.maximum(cw * cw - cb2, 0.0)
        failed_speed = jnp.sqrt(cb2 + (1.0 - state.damage) * shear)
        cw = jnp.where(jnp.asarray(hydro), failed_speed, cw)
    return K, cw
