"""Batched runs: many Params of one scene in one compiled call (vmap), sharded across devices.

    batch = jaxmpm.batch.sweep(params, c_h=[0.02, 0.15, 0.5, 1.0])        # Params with a leading axis
    final, history = jaxmpm.ensemble(scene, batch, t_end=..., n_out=...)  # every leaf: (B, ...)

The scene (and so the compiled step) is shared; only the numbers differ. Every member runs the
same number of scan steps (the largest any member needs); a member whose CFL step is longer
reaches each output time early and then takes zero-length steps, so each member's history is
exactly its single run's on the fixed-length driver (`simulate(..., n_steps=n)`).

Where several devices exist (GPUs, or CPU devices from
XLA_FLAGS=--xla_force_host_platform_device_count=N), the batch is split across them along its
leading axis with `jax.sharding` (padded by repeating the last member, then trimmed); with
several processes (`jax.distributed.initialize`), across all of theirs: every process runs the
same call, and `jaxmpm.distributed.to_host` gathers the results.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jax.typing import ArrayLike

from jaxmpm.model.numbers import OLD_NAMES, warn_old_name
from jaxmpm.model.params import Params, check_params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, check_state
from jaxmpm.numerics.compile import jit
from jaxmpm.run.distributed import to_host
from jaxmpm.run.driver import checkpoint_mode, progress_bar
from jaxmpm.run.planning import check_t_end, count, plan_steps, seconds
from jaxmpm.run.simulate import simulate
from jaxmpm.scenes import initial_state


def stack(items: Sequence[Any]) -> Any:
    """One pytree with a leading axis from a list of equal-structure pytrees (Params or States)."""
    if not items:
        raise ValueError("stack: the list is empty: allowed one or more Params")
    first = jax.tree.structure(items[0])
    for i, item in enumerate(items[1:], 1):
        if jax.tree.structure(item) != first:
            raise ValueError(
                f"stack: item {i} has another structure than item 0 (e.g. Params of another scene: other "
                "phases or constants): allowed items of one scene"
            )
        shapes = [np.shape(a) for a in jax.tree.leaves(item)]
        if shapes != [np.shape(a) for a in jax.tree.leaves(items[0])]:
            raise ValueError(f"stack: item {i} has leaves of other shapes than item 0: allowed items of one scene")
    return jax.tree.map(lambda *a: jnp.stack([jnp.asarray(x) for x in a]), *items)


def member(batch: Any, i: int) -> Any:
    """The i-th member of a batched pytree (i in [-B, B) for a batch of B; an IndexError outside,
    where indexing an array would clamp silently)."""
    if not isinstance(i, (int, np.integer)) or isinstance(i, bool):
        raise TypeError(f"member index {i!r} is invalid: allowed an integer")
    sizes = {int(np.shape(a)[0]) for a in jax.tree.leaves(batch) if np.ndim(a)}
    if sizes and not -min(sizes) <= i < min(sizes):
        raise IndexError(f"member {i} is out of range: allowed -{min(sizes)} <= i < {min(sizes)} (the batch size)")
    return jax.tree.map(lambda a: a[i], batch)


def batch_size(batch: Params) -> int:
    """The common leading (batch) size of every leaf of a Params batch; ValueError where they differ."""
    sizes = {int(np.shape(a)[0]) if np.ndim(a) else -1 for a in jax.tree.leaves(batch)}
    if len(sizes) != 1 or -1 in sizes:
        raise ValueError(
            f"params_batch leaves have leading sizes {sorted(sizes)}: allowed one common "
            "leading (batch) axis on every leaf (build it with jaxmpm.batch.sweep or stack)"
        )
    return sizes.pop()


def sweep(params: Params, **values: ArrayLike) -> Params:
    """Params with a leading batch axis: each named top-level field (c_h, drag, cfl, ...)
    takes the given values in turn; all other numbers are repeated. Several fields must have equal
    lengths (zipped, not crossed: cross them with numpy.meshgrid first). A vector field takes a list
    of vectors, e.g. gravity=[[0, -9.81], [0, -1.62]]."""
    names = {f.name for f in dataclasses.fields(Params)} - {"phases", "body_force"}
    values = _new_names(params, values)
    n = None
    for k, v in values.items():
        if k not in names:
            raise ValueError(f"sweep: {k!r} is not a Params field: allowed {sorted(names)}")
        try:
            v = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"sweep: {k} = {v!r} is invalid: allowed a list of numbers") from None
        each = tuple(np.shape(getattr(params, k)))
        if v.ndim != 1 + len(each) or v.shape[1:] != each or v.shape[0] == 0:
            raise ValueError(
                f"sweep: {k} has shape {v.shape}: allowed a list of values of shape {each} "
                f"({'numbers' if not each else f'{each[0]}-vectors'})"
            )
        if n is not None and v.shape[0] != n:
            raise ValueError(f"sweep: {k} has {v.shape[0]} values, another field {n}: allowed equal lengths")
        n = v.shape[0]
    if n is None:
        raise ValueError("sweep: name at least one field, e.g. sweep(params, c_h=[0.02, 0.15])")
    batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + jnp.shape(a)), params)
    dtype = jnp.result_type(params.cfl)
    return dataclasses.replace(batch, **{k: jnp.asarray(v, dtype) for k, v in values.items()})


def _new_names(params: Params, values: dict) -> dict:
    """sweep's values under the table's names, in their order: an old name (drag_coefficient,
    av_linear, av_quadratic) warns and becomes its new one (an entry of a pair fills that column of
    the pair)."""
    out = {}
    for k, v in values.items():
        if k not in OLD_NAMES:
            out[k] = v
            continue
        warn_old_name(k, stacklevel=4)
        new, index = OLD_NAMES[k]
        if index is None:
            out[new] = v
            continue
        column = np.asarray(v, dtype=float)
        pair = np.asarray(getattr(params, new), dtype=float)
        pair = np.array(out.get(new, values.get(new, np.broadcast_to(pair, column.shape + pair.shape))), dtype=float)
        pair[..., index] = column
        out[new] = pair
    return out


def _shard(batch, n: int):
    """Pad the batch to a multiple of the device count and place it split along axis 0."""
    devices = jax.devices()
    if len(devices) < 2:
        return batch, n
    m = -(-n // len(devices)) * len(devices)
    if m != n:
        batch = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], m - n, axis=0)]), batch)
    sharding = NamedSharding(Mesh(np.asarray(devices), ("batch",)), PartitionSpec("batch"))
    return jax.device_put(batch, sharding), m


def _as_member(i, check, *args):
    """check(*args), its ValueError prefixed with the member's index i (None: one for all)."""
    try:
        check(*args)
    except ValueError as e:
        raise ValueError(str(e) if i is None else f"member {i}: {e}") from None


REPLANS = 2  # how many times `ensemble` runs a batch again when its own plan of n_steps falls short


@functools.lru_cache(maxsize=16)
def _members_fn(scene, t_end, n_out, n_steps, checkpoint, progress):
    """The jitted, vmapped fixed-length run of one batch's members (compiled once per setting, not
    once per call)."""

    def one(p, s):
        return simulate(scene, p, s, t_end=t_end, n_out=n_out, n_steps=n_steps, checkpoint=checkpoint, _report=progress)

    return jit(jax.vmap(one))


def _run_members(scene, params_batch, state, t_end, n_out, n_steps, checkpoint, shard, B, progress=False):
    """The vmapped fixed-length runs of a batch (state batched), split across devices if shard;
    progress: a bar of the members' steps."""
    checkpoint = checkpoint_mode(checkpoint, member(state, 0), n_steps, copies=B)
    if shard:
        (params_batch, state), m = _shard((params_batch, state), B)
    n_per_out = max(1, math.ceil(n_steps / n_out))
    with progress_bar(n_per_out * n_out, f"{scene.name} x{B}", progress):
        final, history = _members_fn(scene, float(t_end), n_out, n_steps, checkpoint, progress)(params_batch, state)
        if progress:
            jax.block_until_ready(final)
    if shard and m != B:
        final, history = jax.tree.map(lambda a: a[:B], (final, history))
    return final, history


def ensemble(
    scene: Scene,
    params_batch: Params,
    state: State | None = None,
    t_end: float | None = None,
    n_out: int | None = None,
    *,
    n_steps: int | None = None,
    checkpoint: bool | str | None = "auto",
    shard: bool = True,
    allow_short: bool = False,
    progress: bool = True,
    safety: float = 1.25,
) -> tuple[State, State]:
    """Run every member of `params_batch` (Params with a leading axis B) from `state` (one State
    for all, or a batched State; default: each member's own initial state) to t_end (s).

    Returns (final, history) like `simulate`, each leaf with a leading axis B. n_steps: scan steps
    per member (default: the most any member's CFL step needs, planned on the host: `safety` >= 1
    times the steps at each member's initial CFL step; an impact, whose shocked material carries
    faster waves, may need 1.4). checkpoint:
    as in `simulate` ("auto", the default, counts the stored states of all B members). shard: split
    the batch across all devices when more than one exists. progress: a bar of the steps run (all
    members advance together). The members' results equal their single runs with the same n_steps
    (tests).

    A member whose CFL step shrinks during the run may not reach t_end in n_steps. Where ensemble
    planned n_steps itself, it then runs the batch again with more steps (a RuntimeWarning says
    how many; up to REPLANS times, where every member got at least half way). Where n_steps was
    given, or still too few, a RuntimeError names the member and the time it reached, unless
    allow_short (then check final.t)."""
    # longer than 60 lines on purpose: the checks of its arguments, then one vmapped run and its replanning;
    # they share the batch's plan
    t_end = scene.t_end if t_end is None else seconds("t_end", t_end)
    n_out = scene.n_out if n_out is None else count("n_out", n_out)
    n_steps = None if n_steps is None else count("n_steps", n_steps)
    B = batch_size(params_batch)
    members = [member(params_batch, i) for i in range(B)]
    for i, p in enumerate(members):  # simulate runs under vmap, where it cannot check them
        _as_member(i, check_params, scene, p)
    if state is None:
        state = stack([initial_state(scene, p) for p in members])
    batched_state = jnp.ndim(state.t) == 1
    if batched_state and int(state.t.shape[0]) != B:
        raise ValueError(f"state has a batch of {state.t.shape[0]}, params_batch {B}: allowed equal sizes")
    for i in range(B if batched_state else 1):
        s = member(state, i) if batched_state else state
        _as_member(i if batched_state else None, check_state, scene, s)
        _as_member(i if batched_state else None, check_t_end, t_end, s.t)
    planned = n_steps is None
    if planned:
        n_steps = max(
            plan_steps(scene, p, member(state, i) if batched_state else state, t_end, safety=safety)
            for i, p in enumerate(members)
        )
    if not batched_state:
        state = jax.tree.map(lambda a: None if a is None else jnp.broadcast_to(a, (B,) + a.shape), state)
    final, history = _run_members(scene, params_batch, state, t_end, n_out, n_steps, checkpoint, shard, B, progress)
    t0 = to_host(state.t)
    reached = to_host(final.t)  # gathered where the batch spans several processes
    short = np.flatnonzero(reached < t_end - 1e-6 * abs(t_end))
    for _ in range(REPLANS if planned else 0):
        if not short.size:
            break
        # the host's plan fell short (a CFL step that shrank by more than its margin): run the
        # batch again with the steps the slowest member's average step would need, and 10% more;
        # not where a member got less than half way (a collapsing step: the error says so)
        rate = float(np.min((reached[short] - t0[short]) / (t_end - t0[short])))
        if rate < 0.5:
            break
        replanned = int(math.ceil(1.1 * n_steps / rate))
        warnings.warn(
            f"{scene.name}: the planned n_steps = {n_steps} reached only t = {reached[short].min():g} s of "
            f"t_end = {t_end:g} s (the CFL step shrank during the run): running the batch again with "
            f"n_steps = {replanned}; pass n_steps, or a safety above {safety:g}, to fix it",
            RuntimeWarning,
            stacklevel=2,
        )
        n_steps = replanned
        final, history = _run_members(scene, params_batch, state, t_end, n_out, n_steps, checkpoint, shard, B, progress)
        reached = to_host(final.t)
        short = np.flatnonzero(reached < t_end - 1e-6 * abs(t_end))
    if short.size and not allow_short:
        raise RuntimeError(
            f"{scene.name}: member(s) {short.tolist()} reached only t = {reached[short].tolist()} s of "
            f"t_end = {t_end:g} s in n_steps = {n_steps} (their CFL step shrank during the run): pass a "
            "larger n_steps, or allow_short=True and check final.t"
        )
    return final, history
