"""simulate(): run a scene to t_end with outputs, by `lax.scan` in chunks.

Two drivers share one step:
  * host-driven (concrete inputs, no `n_steps`): a Python loop over jitted chunks of scan steps,
    adaptive (chunks repeat until each output time is reached), with a progress bar, a check for
    non-finite values after every chunk, and no wasted compilation;
  * fixed-length (inside jit / grad / vmap, or when `n_steps` is given): one scan of `n_steps`
    steps split evenly over the outputs; dt is clipped at each output time and steps after it are
    identities, so the run is reverse-differentiable. `checkpoint` bounds reverse-mode memory on
    long runs by recomputing steps in the backward pass (jax.checkpoint): "steps" keeps every
    step's input state, "nested" (or True) only about 2 sqrt(n) of them for one more forward pass.
"""

from __future__ import annotations

import functools
import math
import os
import signal
import time
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import checkify
from jax.sharding import Mesh
from jax.typing import ArrayLike
from tqdm.auto import tqdm

from jaxmpm.model.params import Params
from jaxmpm.model.sampling import usable_region
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State
from jaxmpm.numerics.compile import jit
from jaxmpm.run.distributed import from_shards, make_sharded_step, mesh_size
from jaxmpm.run.health import CHECKED_FIELDS as CHECKED_FIELDS
from jaxmpm.run.health import find_nonfinite, finite_and_inside, health_fn, reference_step, step_collapse
from jaxmpm.run.planning import RunPlan, compile_seconds, planned_steps
from jaxmpm.run.progress import REPORTS, report_steps
from jaxmpm.run.progress import progress_bar as progress_bar
from jaxmpm.run.signals import Interrupted, StopRequest
from jaxmpm.run.signals import interrupt_on as interrupt_on
from jaxmpm.run.tangents import evolving_tangents
from jaxmpm.step import make_step


def is_traced(tree: Any) -> bool:
    """True where any leaf of the pytree is a JAX tracer (inside jit, grad or vmap)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree))


def stack_states(states: Sequence[State]) -> State:
    """States (a sequence of T pytrees of equal structure) stacked into one with a leading time axis (T, ...)."""
    return jax.tree.map(lambda *a: jnp.stack(a), *states)


@functools.lru_cache(maxsize=32)
def _chunk_fn(scene, length, mesh=None):
    step = _step_of(scene, mesh)

    @jit
    def run(params, state, t_stop, dt):
        def body(s, _):
            return step(params, s, t_stop, dt), None

        return jax.lax.scan(body, state, None, length=length)[0]

    return run


@functools.lru_cache(maxsize=8)
def _checked_chunk_fn(scene, length):
    """The chunk of `_chunk_fn` under `jax.experimental.checkify` (simulate(..., debug=True)): every
    step checks that all particle fields are finite and inside the grid, and every primitive that
    makes a NaN is reported (nan_checks) with its source line. Returns run -> (error, state); the
    first failure names the step of the chunk and the time."""
    step = make_step(scene)
    _, lo, hi = usable_region(scene)

    def run(params, state, t_stop, dt):
        def body(s, i):
            new = step(params, s, t_stop, dt)
            finite, inside = finite_and_inside(new, lo, hi)
            checkify.check(finite, "step {i} of the chunk (t = {t} s): a particle field is not finite", i=i, t=new.t)
            checkify.check(
                inside,
                "step {i} of the chunk (t = {t} s): a particle left the grid",
                i=i,
                t=new.t,
            )
            return new, None

        return jax.lax.scan(body, state, jnp.arange(length))[0]

    return jit(checkify.checkify(run, errors=checkify.user_checks | checkify.nan_checks))


def nested_sizes(n: int) -> tuple[int, int]:
    """(a, b): n steps as a chunks of b steps, b = ceil(sqrt(n)), a = ceil(n / b) (a b >= n)."""
    b = max(1, math.isqrt(n - 1) + 1) if n > 1 else 1
    return -(-n // b), b


def _nested_scan(step, n, params, state, t_stop, dt):
    """n steps toward t_stop with two-level checkpointing: an outer scan over a chunks, each chunk
    (b steps) under jax.checkpoint, each step under jax.checkpoint too. Reverse mode keeps the a
    chunk inputs, then recomputes one chunk at a time keeping its b step inputs: memory ~ (a + b)
    states ~ 2 sqrt(n) instead of n, for one extra forward pass. Padding steps (a b > n) leave the
    state unchanged."""
    a, b = nested_sizes(n)

    def one(carry, i):
        new = step(params, carry, t_stop, dt)
        if a * b == n:
            return new, None
        return jax.tree.map(lambda x, y: jnp.where(i < n, x, y), new, carry), None

    @jax.checkpoint
    def chunk(carry, idx):
        return jax.lax.scan(one, carry, idx)[0], None

    return jax.lax.scan(chunk, state, jnp.arange(a * b).reshape(a, b))[0]


def _step_of(scene, mesh):
    """The step of `scene`, or with a mesh its particle-sharded form (jaxmpm.distributed)."""
    if mesh is None:
        return make_step(scene)
    return make_sharded_step(scene, mesh)


CHECKPOINT_MODES = (False, "steps", "nested")
AUTO_STEPS_BYTES = 2**30  # "auto": "steps" while the stored input states take at most this much


def state_bytes(state: State) -> int:
    """Bytes of one State (works on tracers: shapes and dtypes only)."""
    return sum(int(np.prod(a.shape)) * np.dtype(a.dtype).itemsize for a in jax.tree.leaves(state))


def checkpoint_mode(
    checkpoint: bool | str | None, state: State | None = None, n_steps: int | None = None, copies: int = 1
) -> bool | str:
    """The checkpointing of the fixed-length driver named by simulate's `checkpoint` argument:
    False (None), "steps", "nested" (True), or "auto": "steps" when the n_steps stored input
    states of `copies` runs (an ensemble's members) take at most AUTO_STEPS_BYTES (1 GiB), else
    "nested"."""
    if checkpoint is None or checkpoint is False:
        return False
    if checkpoint is True:
        return "nested"
    if checkpoint == "auto":
        if state is None or n_steps is None:
            return "nested"
        return "steps" if copies * int(n_steps) * state_bytes(state) <= AUTO_STEPS_BYTES else "nested"
    if isinstance(checkpoint, str) and checkpoint in CHECKPOINT_MODES:
        return checkpoint
    raise ValueError(
        f"checkpoint = {checkpoint!r} is invalid: allowed False, True (= 'nested'), 'steps', 'nested' or 'auto'"
    )


@functools.lru_cache(maxsize=32)
def fixed_fn(
    scene: Scene, n_per_out: int, n_out: int, checkpoint: bool | str, mesh: Mesh | None = None, report: bool = False
) -> Callable[..., tuple[State, State]]:
    """Fixed-length driver: n_out intervals of n_per_out steps. checkpoint (`checkpoint_mode`):
    False: reverse mode stores every step's intermediates (memory ~ n_out n_per_out steps'
    residuals, MiB each); "steps": each step under jax.checkpoint, its input state stored and the
    step recomputed in reverse (memory ~ n_out n_per_out states); "nested": `_nested_scan`,
    memory ~ n_out + 2 sqrt(n_per_out) states for one more forward pass. report: tell the host
    the steps done (`report_steps`) up to REPORTS times (nested: after each interval)."""
    step = _step_of(scene, mesh)
    every = max(1, (n_per_out * n_out) // REPORTS)

    def tell(done, now):
        jax.lax.cond(now, lambda: jax.debug.callback(report_steps, done), lambda: None)

    @jit
    def run(params, state, times, dt):
        def inner(s, out):
            t_stop, k = out
            if checkpoint == "nested":
                s = _nested_scan(jax.checkpoint(step), n_per_out, params, s, t_stop, dt)
                if report:
                    tell((k + 1) * n_per_out, True)
            else:
                one = jax.checkpoint(step) if checkpoint == "steps" else step

                def body(s2, i):
                    s2 = one(params, s2, t_stop, dt)
                    if report:
                        done = k * n_per_out + i + 1
                        tell(done, (done % every == 0) | (i == n_per_out - 1))
                    return s2, None

                s = jax.lax.scan(body, s, jnp.arange(n_per_out))[0]
            return s, s

        return jax.lax.scan(
            inner, evolving_tangents(dt is not None, state, (params, times, dt)), (times, jnp.arange(n_out))
        )

    return run


def first_failure(
    scene: Scene, params: Params, state: State, stop: ArrayLike, dt: ArrayLike, length: int, mesh: Mesh | None = None
) -> tuple[int, str] | None:
    """(step, message): the first of `length` steps from `state` toward `stop` after which a
    particle is non-finite or outside the grid, replayed one step at a time, with
    `find_nonfinite`'s message for the state after it; None where no step of them fails. The same
    account of a failure whether the chunk ran with checks (debug) or without."""
    one, health = _chunk_fn(scene, 1, mesh), health_fn(scene)
    for i in range(int(length)):
        state = one(params, state, stop, dt)
        if not bool(health(params, state)[0]):
            here = state
            if mesh is not None:
                here = from_shards(scene, state, mesh_size(mesh))
            return i + 1, find_nonfinite(scene, here) or "a non-finite or out-of-grid particle"
    return None


def _failure_text(found, n_chunk, length, end_message=None) -> str:
    """The account of a failed chunk: `first_failure`'s step and message, else (a replay that does
    not fail, e.g. a NaN that checkify saw in an intermediate only) the message at the chunk's end."""
    if found is None:
        return f"{end_message or 'a non-finite value'} (in chunk {n_chunk} of {length} steps)"
    return f"{found[1]} (step {found[0]} of chunk {n_chunk}, chunks of {length} steps)"


# A chunk (default length) does at most this many particle-steps (and at least 10 steps): its first
# one, after which a run's time is estimated (`RunPlan.first_chunk`), takes seconds, not hours.
CHUNK_PARTICLE_STEPS = 20_000_000


def _warn_outputs_beyond_steps(scene, params, state, t_end, n_out, dt):
    """RuntimeWarning where n_out is more than the steps planned to t_end (each output interval
    takes at least one step: the run would take n_out shorter steps, and save n_out states)."""
    steps = planned_steps(scene, params, state, t_end, None if dt is None else float(dt), safety=1.0)
    if n_out > steps:
        warnings.warn(
            f"{scene.name}: n_out = {n_out} exceeds the about {steps} steps of the run to t_end = {t_end:g} s: "
            f"each output takes at least one step, so the run takes {n_out} shorter steps and saves "
            f"{n_out + 1} states (allowed without this warning: n_out <= {steps})",
            RuntimeWarning,
            stacklevel=5,
        )


def host_driver(
    scene: Scene,
    params: Params,
    state: State,
    t_end: float,
    n_out: int,
    dt: float | None,
    progress: bool,
    chunk: int | None,
    *,
    t0: float | None = None,
    history: list[State] | None = None,
    start_out: int = 0,
    restart_file: str | os.PathLike | None = None,
    restart_every: int = 0,
    debug: bool = False,
    mesh: Mesh | None = None,
    plan: RunPlan | None = None,
    restart_saved: bool = False,
    write_restart: Callable[..., None] | None = None,
) -> tuple[State, State]:
    """The adaptive host-driven run: jitted chunks until each output time (see the module
    docstring). plan: a `RunPlan` told the first chunk's run time (compilation excluded), which may
    refuse the run before anything is saved. restart_saved: `restart_file` already holds this run's
    save (a resumed run): saves append to it from the first. write_restart: the function that
    writes the restart file (`jaxmpm.restart.save`), where restart_file is given."""
    # longer than 60 lines on purpose: one loop whose state (chunk length, output index, time, restart saves,
    # the deferred signal) every part reads and sets; split, the parts would pass all of it around
    t0 = float(state.t) if t0 is None else t0
    times = [t0 + (t_end - t0) * (i + 1) / n_out for i in range(n_out)]
    if chunk is None:
        est = planned_steps(scene, params, state, times[0], None if dt is None else float(dt), safety=1.05)
        chunk = int(min(max(est, 1), 1000, max(10, CHUNK_PARTICLE_STEPS // max(int(np.shape(state.x)[0]), 1))))
    if start_out == 0 and mesh is None:
        _warn_outputs_beyond_steps(scene, params, state, t_end, n_out, dt)
    run = _chunk_fn(scene, int(chunk), mesh)
    if debug:
        checked = _checked_chunk_fn(scene, int(chunk))

        def run(params, state, stop, dt):
            err, new = checked(params, state, stop, dt)
            if err.get() is not None:
                found = first_failure(scene, params, state, stop, dt, chunk, mesh)
                raise FloatingPointError(
                    f"{scene.name}: {_failure_text(found, n_chunks + 1, chunk)}; checkify: {err.get()}"
                )
            return new

    health = health_fn(scene)
    bar = None
    if progress:
        bar = tqdm(
            total=t_end - t0,
            unit="s",
            desc=scene.name,
            bar_format="{l_bar}{bar}| t={n:.3g}/{total:.3g} s [{elapsed}<{remaining}]",
        )
    history = [state] if history is None else list(history)
    n_chunks = 0
    tol = 8 * float(jnp.finfo(state.t.dtype).eps) * max(abs(t_end), t_end - t0)

    saved = {"any": restart_saved}

    def save(next_out):
        if restart_file is not None:
            write_restart(
                restart_file,
                scene,
                params,
                state,
                history,
                t0=t0,
                t_end=t_end,
                n_out=n_out,
                next_out=next_out,
                chunk=chunk,
                dt=None if dt is None else float(dt),
                append=saved["any"],
            )
            saved["any"] = True

    def stop_if_asked(next_out, request):
        if request.signum is None or next_out == n_out:  # none, or the run is complete: its results
            return
        save(next_out)
        where = (
            f"its progress is saved in {restart_file} (t = {float(state.t):.6g} s, {next_out} of {n_out} outputs)"
            if restart_file is not None
            else f"at t = {float(state.t):.6g} s, nothing saved (no restart file)"
        )
        raise Interrupted(request.signum, f"{scene.name}: stopped by {signal.Signals(request.signum).name}: {where}")

    request = StopRequest()
    dt_ref = None if dt is not None else reference_step(scene, params, state, float(health(params, state)[1]))
    if bar is not None:
        bar.update(float(state.t) - t0)
    try:
        request.install()
        for i_out in range(start_out, n_out):
            t_stop = times[i_out]
            stop = jnp.asarray(t_stop, state.t.dtype)
            while float(state.t) < t_stop - tol:
                t_before = float(state.t)
                before, c0, w0 = state, compile_seconds(), time.perf_counter()
                state = run(params, state, stop, dt)
                n_chunks += 1
                healthy, dt_cfl = health(params, state)
                if not bool(healthy):
                    found = first_failure(scene, params, before, stop, dt, chunk, mesh)
                    here = state
                    if found is None and mesh is not None:
                        here = from_shards(scene, state, mesh_size(mesh))
                    end = None if found is not None else find_nonfinite(scene, here)
                    raise FloatingPointError(f"{scene.name}: {_failure_text(found, n_chunks, chunk, end)}")
                if plan is not None and n_chunks == 1:
                    compiled = compile_seconds() - c0
                    plan.first_chunk(chunk, time.perf_counter() - w0 - compiled, compiled)
                if dt is not None and float(dt) > float(dt_cfl) * (1 + 1e-9):
                    raise FloatingPointError(
                        f"{scene.name}: the fixed dt = {float(dt):.6g} s exceeds the CFL limit "
                        f"{float(dt_cfl):.6g} s at t = {float(state.t):.6g} s "
                        f"(speeds grew during the run): use a smaller dt or the CFL step (dt=None)"
                    )
                if not float(state.t) > t_before:
                    raise FloatingPointError(
                        f"{scene.name}: time does not advance at t = {t_before:.6g} s "
                        f"(dt = 0: a wave speed is non-finite or infinite)"
                    )
                if (collapse := step_collapse(scene, state, float(dt_cfl), dt_ref)) is not None:  # a blow-up
                    raise FloatingPointError(f"{scene.name}: {collapse} (after chunk {n_chunks})")
                if bar is not None:
                    bar.update(min(float(state.t), t_end) - t0 - bar.n)  # float32 t may pass t_end by round-off
                if restart_every and n_chunks % restart_every == 0:
                    save(i_out)
                stop_if_asked(i_out, request)
            history.append(state)
            save(i_out + 1)
            stop_if_asked(i_out + 1, request)
    finally:
        request.restore()
        if bar is not None:
            bar.close()
    return state, stack_states(history)
