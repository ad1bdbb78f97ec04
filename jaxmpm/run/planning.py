"""The arguments of a run, checked on the host, and its steps planned: counts, times (s), the CFL
step at a state and a user's dt against it, the memory a grid needs, and `plan_steps`, the
fixed step count that `simulate(n_steps=...)` needs inside jit/grad/vmap."""

from __future__ import annotations

import math
import numbers
import os

import jax
import numpy as np
from jax.typing import ArrayLike

from jaxmpm.model.memory import check_run_memory, run_memory, size_text
from jaxmpm.model.params import Params, check_params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, check_state, phase_slices
from jaxmpm.step import cfl_time_step


def count(name: str, value: object, minimum: int = 1) -> int:
    """An integer >= minimum given as an integer or an integral float; ValueError naming the
    argument for anything else (a fraction is not truncated, a string is not a number)."""
    if not isinstance(value, bool):
        if isinstance(value, (int, np.integer)) or (
            isinstance(value, (float, np.floating)) and float(value).is_integer()
        ):
            if int(value) >= minimum:
                return int(value)
    raise ValueError(f"{name} = {value!r} is invalid: allowed an integer >= {minimum}")


def check_t_end(t_end: object, t0: ArrayLike) -> float:
    """t_end (s) as a float, finite and after the start time t0 (s)."""
    try:
        if isinstance(t_end, (bool, str, bytes)):
            raise TypeError
        t_end = float(t_end)
    except (TypeError, ValueError):
        raise ValueError(
            f"t_end = {t_end!r} is invalid: allowed a number of seconds > state.t = {float(t0)} s"
        ) from None
    if not (math.isfinite(t_end) and t_end > float(t0)):
        raise ValueError(f"t_end = {t_end!r} is invalid: allowed a finite time > state.t = {float(t0)} s")
    return t_end


def seconds(name: str, value: object) -> float:
    """A time argument (s) as a float; ValueError naming it where it is not a number."""
    try:
        if isinstance(value, (bool, str, bytes)):  # "1e-3" is text, not a time: say so rather than parse it
            raise TypeError
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is invalid: allowed a number of seconds") from None


def host_cfl_step(scene: Scene, params: Params, state: State, cfl: float | None = None, checked: bool = False) -> float:
    """cfl_time_step (s) at `state` as a float, outside jit: params and state checked first (unless
    `checked`), and a ValueError where the step is not a finite time > 0 (a speed that overflows
    the dtype, or a wave speed that is not finite), instead of a plan of zero or infinite steps."""
    if not checked:
        check_params(scene, params)
        check_state(scene, state)
    dt = float(cfl_time_step(scene, params, state, cfl))
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(
            f"the CFL time step at t = {float(state.t):g} s is {dt!r}: allowed a finite time > 0 s; a "
            f"particle or wave speed is not finite or too large for {np.asarray(state.v).dtype} (largest "
            f"velocity component: {float(np.abs(np.asarray(state.v)).max()):g} m/s; h = {scene.grid.h:g} m)"
        )
    return dt


def cfl_limit(scene: Scene, params: Params, state: State) -> float:
    """The largest stable dt (s) at `state` for CFL = 1: h / max_p (c_p + |v_p|)."""
    return host_cfl_step(scene, params, state, cfl=1.0)


def check_dt(scene: Scene, params: Params, state: State, dt: float) -> None:
    """ValueError if a user-given dt exceeds the CFL limit params.cfl * h / max(c + |v|)."""
    limit = host_cfl_step(scene, params, state, checked=True)
    if not dt > 0:
        raise ValueError(
            f"dt = {dt!r} is invalid: allowed (0, {limit:.6g}] s (the CFL limit at cfl = {float(params.cfl):g})"
        )
    if dt > limit * (1 + 1e-12):
        raise ValueError(
            f"dt = {dt:.6g} s is above the CFL limit: allowed (0, {limit:.6g}] s "
            f"(params.cfl = {float(params.cfl):g} times cfl_limit = {limit / float(params.cfl):.6g} s, "
            f"h = {scene.grid.h:g} m)"
        )


def plan_steps(
    scene: Scene, params: Params, state: State, t_end: float, dt: float | None = None, safety: float = 1.25
) -> int:
    """Number of scan steps that reach t_end (s): (t_end - t) / dt with a safety margin for the CFL
    step shrinking during the run (dt: a fixed step in s, checked against the CFL limit; None: the
    number of CFL steps at `state` times `safety` >= 1). Call it outside jit/grad/vmap and pass it
    as `n_steps`."""
    check_params(scene, params)
    check_state(scene, state)
    return planned_steps(scene, params, state, t_end, dt, safety)


def planned_steps(
    scene: Scene, params: Params, state: State, t_end: float, dt: float | None = None, safety: float = 1.25
) -> int:
    """`plan_steps` for params and state already checked (the host driver's, whose state may span
    several processes, where check_state cannot read it)."""
    span = check_t_end(t_end, state.t) - float(state.t)
    if dt is not None:
        dt = seconds("dt", dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt = {dt!r} is invalid: allowed a finite time step > 0 s")
        check_dt(scene, params, state, dt)
        return max(1, math.ceil(span / dt * (1 + 1e-9)))
    if isinstance(safety, bool) or not (isinstance(safety, numbers.Real) and math.isfinite(safety) and safety >= 1):
        raise ValueError(
            f"safety = {safety!r} is invalid: allowed a number >= 1 (the factor of steps over the plan "
            "at the initial CFL step)"
        )
    return max(1, math.ceil(safety * span / host_cfl_step(scene, params, state, checked=True)))


def acceleration_bound(scene: Scene, params: Params, state: State, dt: float | None = None) -> None:
    """ValueError before a run whose gravity (plus a phase's body force) moves a particle at rest
    more than a cell in one step: in a step of dt a constant acceleration a adds a dt to the speed
    and a dt^2 to the position (PHYSICS 2.1's symplectic update), and the CFL step (the largest,
    at rest) cannot see the speed the step itself adds; |a| dt0^2 <= h at the initial step dt0
    (the fixed dt, else the CFL step) keeps it under a cell per step, and the CFL step shrinks
    as the speed grows, so the bound holds for the whole run where it holds at the start."""
    accel = []
    if scene.gravity is not None:
        accel.append(("gravity", np.asarray(params.gravity, float)))
    if getattr(scene, "body_force", False):
        gravity = np.asarray(params.gravity, float) if scene.gravity is not None else 0.0
        accel += [
            (f"gravity + params.body_force['{k}']", gravity + np.asarray(v, float))
            for k, v in params.body_force.items()
        ]
    if not accel:
        return
    step = float(dt) if dt is not None else host_cfl_step(scene, params, state, checked=True)
    h = scene.grid.h
    for name, a in accel:
        size = float(np.linalg.norm(a))
        if not math.isfinite(size) or size * step**2 > h:
            raise ValueError(
                f"{name} = {a.tolist()} m/s^2 is too large for the grid and time step: in one step of "
                f"dt = {step:.3g} s it moves a particle at rest {size * step**2:.3g} m, more than a cell "
                f"(h = {h:g} m): allowed |{name}| <= h / dt^2 = {h / step**2:.3g} m/s^2 (or a smaller time step: "
                "a smaller cfl or a fixed dt)"
            )


def _free_faces(scene) -> set:
    """The grid faces ('x_lo', ...) without a wall (free: a particle through them leaves the grid)."""
    walls = {face for face, kind in getattr(scene.boundary, "faces", ()) if kind != "free"}
    return (
        {f"{a}_{s}" for a in "xyz"[: scene.dim] for s in ("lo", "hi")}
        - walls
        - ({"x_lo"} if scene.axisymmetric else set())
    )


def flight_warnings(scene: Scene, state: State, t_end: float) -> list[str]:
    """A line for each phase whose fastest particle, unstopped, would leave the grid through a face
    without a wall before t_end (s): a speed out of scale with the grid and the run (1e5 m/s on
    a 1 m grid) fails after some steps; a collision may stop or turn it, so this is a warning."""
    x, v = np.asarray(state.x, float), np.asarray(state.v, float)
    lo, hi = np.asarray(scene.grid.origin, float), np.asarray(scene.grid.hi, float)
    free = _free_faces(scene)
    span = float(t_end) - float(state.t)
    out = []
    for phase, sl in zip(scene.phases, phase_slices(scene)):
        if sl.stop <= sl.start:
            continue
        xs, vs = x[sl], v[sl]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_hi = np.where(vs > 0, (hi - xs) / vs, np.inf)
            t_lo = np.where(vs < 0, (lo - xs) / vs, np.inf)
        first = np.inf
        for axis in range(scene.dim):
            a = "xyz"[axis]
            if f"{a}_hi" in free:
                first = min(first, float(np.min(t_hi[:, axis])))
            if f"{a}_lo" in free:
                first = min(first, float(np.min(t_lo[:, axis])))
        if first < span:
            speed = float(np.max(np.linalg.norm(vs, axis=1)))
            out.append(
                f"phase {phase.name!r} moves at up to {speed:.3g} m/s: unstopped, it would leave the grid through a "
                f"face without a wall at t = {float(state.t) + first:.3g} s, before t_end = {float(t_end):g} s "
                "(a particle outside the grid stops the run: check the speed's units, or enlarge the grid or add walls)"
            )
    return out


# --- the run's plan and its time estimate ------------------------------------------------------

MAX_MINUTES = 60.0  # a run estimated to take longer asks for confirmation (yes=True, --yes)
MAX_MINUTES_ENV = "JAXMPM_MAX_MINUTES"


def max_minutes(value: float | None = None) -> float:
    """The confirmation threshold in minutes: `value`, else $JAXMPM_MAX_MINUTES, else MAX_MINUTES."""
    where = "max_minutes"
    if value is None:
        text = os.environ.get(MAX_MINUTES_ENV)
        if text is None:
            return MAX_MINUTES
        where = f"${MAX_MINUTES_ENV}"
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"{where} = {text!r} is invalid: allowed a number of minutes > 0") from None
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not value > 0 or math.isnan(value):
        raise ValueError(f"{where} = {value!r} is invalid: allowed a number of minutes > 0")
    return float(value)


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    if s < 2 * 86400:
        return f"{s / 3600:.3g} h"
    return f"{s / 86400:.3g} days"


class RunPlan:
    """What a host-driven run will do, known before it starts: particles, nodes, planned steps (at
    the initial CFL step, or the fixed dt), and the memory it needs at least (the history of
    n_out + 1 states it keeps, and the grid at NUMBERS_PER_NODE numbers per node and field); and
    after its first chunk, the time it will take (`first_chunk`), against a threshold in minutes
    above which it runs only when confirmed (yes)."""

    def __init__(self, scene, params, state, t_end, n_out, dt=None, minutes=None, yes=False, report=None):
        self.scene, self.t_end, self.n_out, self.yes, self.report = scene, float(t_end), int(n_out), bool(yes), report
        self.minutes = max_minutes(minutes)
        self.particles = int(np.shape(state.x)[0])
        self.nodes = math.prod(c + 1 for c in scene.grid.cells)
        self.itemsize = np.dtype(state.x.dtype).itemsize
        self.state_bytes = sum(int(np.prod(np.shape(a))) * np.dtype(a.dtype).itemsize for a in _leaves(state))
        self.memory = run_memory(scene, self.particles, self.n_out, self.itemsize, self.state_bytes)[0]
        compile_seconds()  # listening for compilations from here on
        self.steps = planned_steps(scene, params, state, t_end, dt, safety=1.0)
        self.seconds = None

    def check_memory(self) -> None:
        """ValueError where the memory the run needs at least exceeds the memory available."""
        check_run_memory(self.scene, self.particles, self.n_out, self.itemsize, self.state_bytes)

    def text(self) -> str:
        s = self.scene
        return (
            f"plan: {self.particles:,} particles, {self.nodes:,} nodes x {s.n_fields} velocity field(s), about "
            f"{self.steps:,} steps to t = {self.t_end:g} s (at the initial CFL step), memory at least "
            f"{size_text(self.memory)}; time estimated after the first chunk (runs over {self.minutes:g} min "
            "need --yes)"
        )

    def first_chunk(self, steps: int, seconds: float, compile_seconds: float) -> None:
        """The time of the whole run from its first chunk of `steps` steps, which took `seconds`
        (compilation excluded); reported, and a ValueError where it exceeds the threshold unconfirmed."""
        per_step = max(seconds, 0.0) / max(int(steps), 1)
        self.seconds = per_step * self.steps
        line = (
            f"first chunk: {steps} steps in {seconds:.3g} s (compilation {compile_seconds:.3g} s): the run's "
            f"{self.steps:,} steps take about {_duration(self.seconds)}"
        )
        if self.report is not None:
            self.report(line)
        if self.seconds > 60 * self.minutes and not self.yes:
            raise ValueError(
                f"{self.scene.name}: the run is estimated to take about {_duration(self.seconds)} "
                f"({self.steps:,} steps to t_end = {self.t_end:g} s at {per_step:.3g} s per step, from its "
                f"first chunk), over the {self.minutes:g} min allowed without confirmation: run it with "
                f"--yes (Python: yes=True), or raise --max-minutes (max_minutes=, ${MAX_MINUTES_ENV}), or "
                "make it smaller (a shorter t_end, a coarser resolution)"
            )


def _leaves(state):
    return [a for a in jax.tree.leaves(state) if a is not None]


_COMPILE = {"seconds": 0.0, "listening": False}
_COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
)


def compile_seconds() -> float:
    """Seconds this process has spent tracing and compiling JAX functions since the first call
    (jax.monitoring's compile events): a chunk's wall time less the increase is its run time."""
    if not _COMPILE["listening"]:

        def listen(event, duration, **_):
            if event in _COMPILE_EVENTS:
                _COMPILE["seconds"] += float(duration)

        jax.monitoring.register_event_duration_secs_listener(listen)
        _COMPILE["listening"] = True
    return _COMPILE["seconds"]
