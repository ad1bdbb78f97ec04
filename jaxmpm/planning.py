"""The arguments of a run, checked on the host, and its steps planned: counts, times (s), the CFL
step at a state and a user's dt against it, the memory a grid needs, and `plan_steps`, the
fixed step count that `simulate(n_steps=...)` needs inside jit/grad/vmap."""
from __future__ import annotations

import math
import numbers

import numpy as np

from jaxmpm.params import check_params
from jaxmpm.state import check_state, lattice_cells
from jaxmpm.step import cfl_time_step


def count(name: str, value, minimum: int = 1) -> int:
    """An integer >= minimum given as an integer or an integral float; ValueError naming the
    argument for anything else (a fraction is not truncated, a string is not a number)."""
    if not isinstance(value, bool):
        if isinstance(value, (int, np.integer)) or (isinstance(value, (float, np.floating)) and float(value).is_integer()):
            if int(value) >= minimum:
                return int(value)
    raise ValueError(f"{name} = {value!r} is invalid: allowed an integer >= {minimum}")


def check_t_end(t_end, t0) -> float:
    """t_end (s) as a float, finite and after the start time t0 (s)."""
    try:
        if isinstance(t_end, (bool, str, bytes)):
            raise TypeError
        t_end = float(t_end)
    except (TypeError, ValueError):
        raise ValueError(f"t_end = {t_end!r} is invalid: allowed a number of seconds > state.t = {float(t0)} s") from None
    if not (math.isfinite(t_end) and t_end > float(t0)):
        raise ValueError(f"t_end = {t_end!r} is invalid: allowed a finite time > state.t = {float(t0)} s")
    return t_end


def seconds(name: str, value) -> float:
    """A time argument (s) as a float; ValueError naming it where it is not a number."""
    try:
        if isinstance(value, (bool, str, bytes)):      # "1e-3" is text, not a time: say so rather than parse it
            raise TypeError
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is invalid: allowed a number of seconds") from None


def host_cfl_step(scene, params, state, cfl=None, checked=False) -> float:
    """cfl_time_step (s) at `state` as a float, outside jit: params and state checked first (unless
    `checked`), and a ValueError where the step is not a finite time > 0 (a speed that overflows
    the dtype, or a wave speed that is not finite), instead of a plan of zero or infinite steps."""
    if not checked:
        check_params(scene, params)
        check_state(scene, state)
    dt = float(cfl_time_step(scene, params, state, cfl))
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"the CFL time step at t = {float(state.t):g} s is {dt!r}: allowed a finite time > 0 s; a "
                         f"particle or wave speed is not finite or too large for {np.asarray(state.v).dtype} (largest "
                         f"velocity component: {float(np.abs(np.asarray(state.v)).max()):g} m/s; h = {scene.grid.h:g} m)")
    return dt


def cfl_limit(scene, params, state) -> float:
    """The largest stable dt (s) at `state` for CFL = 1: h / max_p (c_p + |v_p|)."""
    return host_cfl_step(scene, params, state, cfl=1.0)


def check_dt(scene, params, state, dt) -> None:
    """ValueError if a user-given dt exceeds the CFL limit params.cfl * h / max(c + |v|)."""
    limit = host_cfl_step(scene, params, state, checked=True)
    if not dt > 0:
        raise ValueError(f"dt = {dt!r} is invalid: allowed (0, {limit:.6g}] s (the CFL limit at cfl = {float(params.cfl):g})")
    if dt > limit * (1 + 1e-12):
        raise ValueError(f"dt = {dt:.6g} s is above the CFL limit: allowed (0, {limit:.6g}] s "
                         f"(params.cfl = {float(params.cfl):g} times cfl_limit = {limit / float(params.cfl):.6g} s, "
                         f"h = {scene.grid.h:g} m)")


NUMBERS_PER_NODE = 16     # a lower bound: a step holds far more per node and velocity field than this


def available_memory() -> int | None:
    """Bytes of memory available to new allocations (Linux /proc/meminfo), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_memory(scene, state) -> None:
    """ValueError before a run whose grid cannot fit in the memory available: NUMBERS_PER_NODE
    numbers per node and velocity field is less than any step holds, so a refusal is certain, not a
    guess (a larger grid can still run out of memory later)."""
    check_scene_memory(scene, np.asarray(state.x).dtype.itemsize)


def lattice_points(grid, phase) -> int:
    """The number of lattice points `state.sample_phase` lays over the phase's bounding box (ppc^d per
    cell of the grid that the box touches), before it keeps those inside the geometry."""
    c_lo, c_hi = lattice_cells(grid, phase)
    return math.prod(max(int(b - a), 0) * phase.ppc for a, b in zip(c_lo, c_hi))


def check_scene_memory(scene, itemsize: int = 8) -> None:
    """ValueError before particles are sampled where the grid (as `check_memory`) or a phase's
    particle lattice cannot fit in the memory available: the lattice's positions alone, d numbers
    per point, are less than sampling holds, so a refusal is certain, not a guess."""
    avail = available_memory()
    if avail is None:
        return
    nodes = math.prod(c + 1 for c in scene.grid.cells)
    need = nodes * scene.n_fields * NUMBERS_PER_NODE * itemsize
    if need > avail:
        raise ValueError(f"grid.cells = {list(scene.grid.cells)} is invalid: its {nodes:,} nodes x {scene.n_fields} velocity "
                         f"field(s) need more than {need / 2**30:.1f} GiB of memory and {avail / 2**30:.1f} GiB are "
                         "available (allowed a smaller grid: fewer cells, or a larger h with --opt resolution / grid.h)")
    for phase in scene.phases:
        points = lattice_points(scene.grid, phase)
        need = points * scene.dim * 8          # sampled in float64 on the host
        if need > avail:
            raise ValueError(f"phase.{phase.name}.ppc = {phase.ppc} is invalid with grid.h = {scene.grid.h:g} m: sampling "
                             f"lays {points:,} particle positions over the phase's bounding box, more than "
                             f"{need / 2**30:.1f} GiB of memory where {avail / 2**30:.1f} GiB are available (allowed fewer "
                             "particles: a smaller ppc, or a larger h with --opt resolution / grid.h)")


def plan_steps(scene, params, state, t_end, dt=None, safety=1.25) -> int:
    """Number of scan steps that reach t_end (s): (t_end - t) / dt with a safety margin for the CFL
    step shrinking during the run (dt: a fixed step in s, checked against the CFL limit; None: the
    number of CFL steps at `state` times `safety` >= 1). Call it outside jit/grad/vmap and pass it
    as `n_steps`."""
    check_params(scene, params)
    check_state(scene, state)
    return _planned_steps(scene, params, state, t_end, dt, safety)


def _planned_steps(scene, params, state, t_end, dt=None, safety=1.25) -> int:
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
        raise ValueError(f"safety = {safety!r} is invalid: allowed a number >= 1 (the factor of steps over the plan "
                         "at the initial CFL step)")
    return max(1, math.ceil(safety * span / host_cfl_step(scene, params, state, checked=True)))
