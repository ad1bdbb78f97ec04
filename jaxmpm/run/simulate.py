"""simulate(): run a scene to t_end with outputs; the two drivers it chooses between are in
`jaxmpm.run.driver` (host-driven chunks, or one fixed-length scan)."""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh

from jaxmpm.io.files import check_new
from jaxmpm.model.memory import check_scene_memory
from jaxmpm.model.params import Params, check_params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, check_state, check_state_dtypes
from jaxmpm.run import distributed, restart
from jaxmpm.run.driver import checkpoint_mode, fixed_fn, host_driver, is_traced, progress_bar
from jaxmpm.run.planning import RunPlan, acceleration_bound, check_dt, check_t_end, count, flight_warnings, seconds


def simulate(
    scene: Scene,
    params: Params,
    state: State,
    t_end: float | None = None,
    n_out: int | None = None,
    *,
    dt: float | None = None,
    n_steps: int | None = None,
    progress: bool = True,
    checkpoint: bool | str | None = "auto",
    chunk: int | None = None,
    restart_file: str | os.PathLike | None = None,
    restart_every: int = 10,
    debug: bool = False,
    mesh: Mesh | None = None,
    overwrite: bool = False,
    allow_short: bool = False,
    yes: bool = False,
    max_minutes: float | None = None,
    announce: Callable[[list[str]], None] | None = None,
    _report: bool | None = None,
) -> tuple[State, State]:
    """Advance `state` to t_end (s) and return (final, history).

    history: the State at n_out + 1 evenly spaced times from state.t to t_end (the initial state
    first), as a State whose arrays have a leading axis of length n_out + 1.
    dt: a fixed time step (s), checked against the CFL limit; default: the CFL step each step.
    n_steps: total scan steps (fixed-length driver); required inside jit/grad/vmap, where the
      host cannot plan (use `plan_steps` outside). Outside them, a run whose n_steps do not reach
      t_end (by more than half a step) raises a RuntimeError naming the time reached, unless
      allow_short (then check final.t). progress: a tqdm bar of simulated time (host driver), or of
      steps (n_steps given, outside jit/grad/vmap; `ensemble` draws one for its batch).
    checkpoint: how reverse mode through the fixed-length driver bounds its memory (a forward run
      computes the same either way).
      "auto" (default): "steps" while n_steps States take at most 1 GiB (`checkpoint_mode`), else
        "nested".
      "steps": each step recomputed once in reverse from its stored input state: memory grows as
        the number of steps (one State each), the gradient costs about 4-5 forward runs.
      "nested" or True: two-level checkpointing (`_nested_scan`): memory grows as the square root
        of the steps per output, for one more forward pass (about 5-6 forward runs).
      False: no checkpointing; every step's intermediates are stored (MiB per step), and reading
        them back is slower than recomputing the step: on the built-in scenes of 200 particles or
        more the gradient took 1.0-2.1x the time of "steps" at 4-26x its memory (0.8x on a
        50-particle column; benchmarks/grad_by_scene.py --checkpoint steps,none).
      (Costs measured on the coarse debris cloud, benchmarks/grad_cost.py.)
    chunk: steps per jitted chunk (host driver).
    restart_file: path of a restart file to save every `restart_every` chunks and at each output
      (host driver); `jaxmpm.restart.resume(restart_file)` continues the run bit-identically. An
      existing file there is refused (FileExistsError: resume it, or delete it) unless overwrite=True.
    debug: run the host driver's chunks under `jax.experimental.checkify` (slower): the run stops
      at the first step with a non-finite or out-of-grid particle, naming the step and time, or at
      the first primitive that makes a NaN, naming it and its source line.
    mesh: a `jaxmpm.distributed.particle_mesh`: the particles split across its devices, the
      nodal sums completed across them (`jaxmpm.distributed`); the state passed and the results
      are in the scene's particle order. Not with restart_file or debug.
    yes, max_minutes, announce (host driver): before the run its plan is made (particles, nodes,
      planned steps, the memory it needs: more than is available is refused) and after its first
      chunk its time is estimated (`jaxmpm.run.planning.RunPlan`); a run estimated over max_minutes
      (None: $JAXMPM_MAX_MINUTES, else 60) raises a ValueError before it saves anything, unless
      yes=True. announce: a callable given the plan's and the estimate's lines (`jaxmpm run`: print).
    """
    # longer than 60 lines on purpose: its arguments' checks one after another, then the choice of driver
    t_end = scene.t_end if t_end is None else seconds("t_end", t_end)
    n_out = scene.n_out if n_out is None else count("n_out", n_out)
    n_steps = None if n_steps is None else count("n_steps", n_steps)
    chunk = None if chunk is None else count("chunk", chunk)
    checkpoint = checkpoint_mode(checkpoint, state, n_steps)
    traced = is_traced((params, state))
    if traced and isinstance(state, State):
        check_state_dtypes(state)
    if not traced:
        check_params(scene, params)
        check_state(scene, state)
        check_memory(scene, state)
        t_end = check_t_end(t_end, state.t)
        if dt is not None:
            check_dt(scene, params, state, seconds("dt", dt))
        acceleration_bound(scene, params, state, None if dt is None else seconds("dt", dt))
    plan = None
    if not traced and n_steps is None:
        for line in flight_warnings(scene, state, t_end):
            warnings.warn(f"{scene.name}: {line}", UserWarning, stacklevel=2)
        plan = RunPlan(
            scene, params, state, t_end, n_out, None if dt is None else seconds("dt", dt), max_minutes, yes, announce
        )
        plan.check_memory()
        if announce is not None:
            announce(plan.text())
    if (traced or n_steps is not None) and debug:
        raise ValueError(
            "debug=True is invalid with n_steps or inside jit/grad/vmap (the fixed-length driver checks "
            "nothing): allowed debug=False there, or no n_steps outside them"
        )
    if restart_file is not None and not isinstance(restart_file, (str, os.PathLike)):
        raise ValueError(f"restart_file = {restart_file!r} is invalid: allowed a path (str or pathlib.Path) or None")
    if restart_file is not None:
        if traced or n_steps is not None:
            raise ValueError(
                "restart_file is invalid with n_steps or inside jit/grad/vmap (the fixed-length driver "
                "saves nothing): allowed restart_file=None there, or no n_steps outside them"
            )
        check_new(restart_file, overwrite=overwrite)
    shards = 1
    if mesh is not None:
        if restart_file is not None or debug:
            raise ValueError("mesh is invalid with restart_file or debug: allowed mesh=None for those runs")
        shards = distributed.mesh_size(mesh)
        state = distributed.to_shards(scene, state, mesh)
    t0 = None if traced else float(state.t)
    final, history = _run(
        scene,
        params,
        state,
        t_end,
        n_out,
        dt,
        n_steps,
        progress,
        checkpoint,
        chunk,
        restart_file,
        restart_every,
        debug,
        traced,
        mesh,
        _report,
        plan,
    )
    if n_steps is not None and not traced and not allow_short:
        _check_reached(scene, final.t, t0, t_end, n_steps)
    if mesh is None:
        return final, history
    return distributed.from_shards(scene, final, shards), distributed.from_shards(
        scene, history, shards, time_axis=True
    )


def check_memory(scene: Scene, state: State) -> None:
    """ValueError before a run whose grid cannot fit in the memory available: NUMBERS_PER_NODE
    numbers per node and velocity field is less than any step holds, so a refusal is certain, not a
    guess (a larger grid can still run out of memory later)."""
    check_scene_memory(scene, np.asarray(state.x).dtype.itemsize)


def _check_reached(scene, t, t0, t_end, n_steps):
    """RuntimeError when a fixed-length run ends short of t_end by more than half of a step of
    (t_end - t0) / n_steps: its n_steps were too few (or its CFL step shrank during the run)."""
    reached = float(np.max(np.asarray(t)))
    if reached < t_end - 0.5 * (t_end - t0) / n_steps:
        raise RuntimeError(
            f"{scene.name}: the run reached only t = {reached:.6g} s of t_end = {t_end:g} s in "
            f"n_steps = {n_steps}: pass a larger n_steps (jaxmpm.plan_steps(scene, params, state, t_end) "
            "plans them), or allow_short=True and check final.t"
        )


def _run(
    scene,
    params,
    state,
    t_end,
    n_out,
    dt,
    n_steps,
    progress,
    checkpoint,
    chunk,
    restart_file,
    restart_every,
    debug,
    traced,
    mesh,
    report=None,
    plan=None,
):
    """report: whether the fixed-length driver tells a progress bar its steps (None: where progress
    is on outside jit/grad/vmap; `ensemble` sets it for its vmapped members and draws the bar)."""
    dtype = state.t.dtype
    dt_arr = None if dt is None else jnp.asarray(dt, dtype)
    if traced or n_steps is not None:
        if n_steps is None:
            raise ValueError(
                "n_steps is required inside jit/grad/vmap: compute it outside with "
                "jaxmpm.plan_steps(scene, params, state, t_end) and pass n_steps=..."
            )
        n_per_out = max(1, math.ceil(int(n_steps) / n_out))
        t0 = state.t
        times = t0 + (t_end - t0) * jnp.arange(1, n_out + 1, dtype=dtype) / n_out
        report = (progress and not traced) if report is None else report
        with progress_bar(n_per_out * n_out, scene.name, report and not traced):
            final, hist = fixed_fn(scene, n_per_out, n_out, checkpoint, mesh, report)(params, state, times, dt_arr)
            if report:
                jax.block_until_ready(final)
        history = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), state, hist)
        return final, history
    if restart_file is not None and not (isinstance(restart_every, int) and restart_every >= 1):
        raise ValueError(f"restart_every = {restart_every!r} is invalid: allowed an integer >= 1 (chunks)")
    return host_driver(
        scene,
        params,
        state,
        t_end,
        n_out,
        dt_arr,
        progress,
        chunk,
        restart_file=restart_file,
        restart_every=restart_every,
        debug=debug,
        mesh=mesh,
        plan=plan,
        write_restart=restart.save,
    )
