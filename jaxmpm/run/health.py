"""A run's health: whether its particles are finite and inside the grid (traced, each chunk), and
where a failed state fails (on the host: the field, the phase and the particle)."""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from jaxmpm.model.params import Params
from jaxmpm.model.sampling import usable_region
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, phase_slices
from jaxmpm.numerics.compile import jit
from jaxmpm.step import cfl_time_step

CHECKED_FIELDS = ("x", "v", "stress", "volume", "energy")  # the particle fields a run checks are finite


def finite_and_inside(state: State, lo: ArrayLike, hi: ArrayLike) -> tuple[jax.Array, jax.Array]:
    """(finite, inside): whether every particle's CHECKED_FIELDS are finite, and every particle lies
    in the grid's usable region [lo, hi] (`usable_region`); two boolean scalars, traceable."""
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(getattr(state, n))) for n in CHECKED_FIELDS]))
    lo, hi = jnp.asarray(lo), jnp.asarray(hi)
    # compared in the wider of the two dtypes (a float32 state against float64 bounds: in float64)
    x = state.x.astype(np.promote_types(state.x.dtype, lo.dtype))
    return finite, jnp.all((x >= lo) & (x <= hi))


@functools.lru_cache(maxsize=32)
def health_fn(scene: Scene) -> Callable[[Params, State], tuple[jax.Array, jax.Array]]:
    """Jitted on-device check of a chunk's result: (everything finite and inside the grid, CFL dt).
    Only these two scalars cross to the host each chunk; arrays do only when a check fails."""
    _, lo, hi = usable_region(scene)

    @jit
    def health(params, state):
        ok, inside = finite_and_inside(state, lo, hi)
        return ok & inside, cfl_time_step(scene, params, state)

    return health


# A CFL step below this fraction of the run's reference step stops the run: its fastest wave has
# grown a thousandfold, which no sound flow does (the run would crawl on in ever shorter steps)
STEP_COLLAPSE = 1e-3


def reference_step(scene: Scene, params: Params, state: State, dt_cfl: float) -> float | None:
    """The CFL step (s) a sound run keeps above STEP_COLLAPSE of: the smaller of the run's first CFL
    step dt_cfl and the step of a body falling through the grid's extent under gravity, cfl h /
    sqrt(2 |g| L) (a cold, soft body may gain its speed that way). None (no check) with body forces,
    whose accelerations are the user's, or where dt_cfl is not a positive finite step."""
    if scene.body_force or not (np.isfinite(dt_cfl) and dt_cfl > 0):
        return None
    g = float(np.linalg.norm(np.asarray(params.gravity, float)))
    if g == 0.0:
        return dt_cfl
    extent = float(np.linalg.norm(np.asarray(scene.grid.hi, float) - np.asarray(scene.grid.origin, float)))
    return min(dt_cfl, float(params.cfl) * scene.grid.h / np.sqrt(2 * g * extent))


def step_collapse(scene: Scene, state: State, dt_cfl: float, dt_ref: float | None) -> str | None:
    """None if there is no reference step (dt_ref None) or the CFL step dt_cfl (s) is at least
    STEP_COLLAPSE of the reference dt_ref (s), else a message naming the fastest particle (its
    phase, speed, position and internal energy)."""
    if dt_ref is None or not dt_cfl < STEP_COLLAPSE * dt_ref:
        return None
    v = np.asarray(state.v)
    i = int(np.argmax(np.sum(v * v, axis=-1)))
    return (
        f"the run is blowing up at t = {float(state.t):.6g} s: its CFL step has fallen to {dt_cfl:.3g} s, "
        f"1/{dt_ref / dt_cfl:.0f} of its reference step {dt_ref:.3g} s (allowed: at least {STEP_COLLAPSE:g} "
        f"of it); the fastest particle, {i} of phase {_phase_of(scene, i)!r}, moves at "
        f"{float(np.linalg.norm(v[i])):.3g} m/s at x = {np.asarray(state.x[i]).tolist()} m with a specific "
        f"internal energy of {float(np.asarray(state.energy)[i]):.3g} J/kg"
    )


def _phase_of(scene, i):
    return next(p.name for p, sl in zip(scene.phases, phase_slices(scene)) if sl.start <= i < sl.stop)


def find_nonfinite(scene: Scene, state: State) -> str | None:
    """None if every particle value is finite and every particle inside the grid, else a message
    naming the field, the phase and the particle index."""
    for name in CHECKED_FIELDS:
        a = np.asarray(getattr(state, name))
        bad = ~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            return f"non-finite {name} at t = {float(state.t):.6g} s: phase {_phase_of(scene, i)!r}, particle {i}"
    _, lo, hi = usable_region(scene)
    x = np.asarray(state.x)
    out = np.any((x < lo) | (x > hi), axis=1)
    if out.any():
        i = int(np.argmax(out))
        return (
            f"particle {i} of phase {_phase_of(scene, i)!r} is outside the grid at t = {float(state.t):.6g} s: "
            f"x = {x[i].tolist()} m, allowed [{lo.tolist()}, {hi.tolist()}] m (enlarge the grid or add walls)"
        )
    return None
