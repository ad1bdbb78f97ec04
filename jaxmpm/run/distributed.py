"""One simulation on several devices: the particles split across a mesh axis, the grid on every device.

Each device holds an equal block of every phase's particles. The step runs under `jax.shard_map`:
each device scatters its particles into a full nodal array, the nodal arrays are summed across
the devices (`psum`), the grid update is repeated on every device (the grid is small beside the
particles), and each device gathers back to its own particles; the particle maxima of the step
(the CFL step, the mass floor) are taken across the devices (`pmax`). Nothing else changes: the
physics is `jaxmpm.step` itself (`make_step(scene, shards, axis_name)`).

    mesh = jaxmpm.distributed.particle_mesh()           # all devices, axis 'particles'
    final, history = jaxmpm.simulate(scene, params, state, mesh=mesh)

Results equal the one-device run to round-off (sums in another order). The State a user passes
and gets back is in the scene's particle order; inside, the particles are permuted so that each
device's block holds a contiguous part of every phase (`shard_order`), and a phase whose count
is not a multiple of the devices is filled up with copies of its last particle that carry eps^2 of
its mass and volume (`padding_scale`: they move exactly as their twin, their share of the nodal
sums is below round-off, and they are dropped from the results).

Several hosts (processes): call `jax.distributed.initialize(...)` in every process first (JAX's
own setup; on CPU hosts, set `jax.config.update("jax_cpu_collectives_implementation", "gloo")`
before it), then run the same program in every process: `particle_mesh()` takes all processes'
devices. `simulate` returns the State replicated on every process (NumPy reads it as it is);
`jaxmpm.ensemble` returns the batch split across the processes, and `to_host` gathers it to NumPy
on every process (for plots and files). On one machine, test with two devices of
one process (`XLA_FLAGS=--xla_force_host_platform_device_count=2`) or two processes on
localhost (tests/test_distributed.py runs both).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P
from jax.typing import DTypeLike

from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, phase_slices
from jaxmpm.step import make_step

AXIS = "particles"


def particle_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-axis Mesh named 'particles' over `devices` (default: all of jax.devices())."""
    devices = jax.devices() if devices is None else list(devices)
    if len(devices) < 1:
        raise ValueError("devices = [] is invalid: allowed one device or more")
    return Mesh(np.array(devices), (AXIS,))


def mesh_size(mesh: Mesh) -> int:
    """The number of devices of a particle mesh; ValueError for any other mesh."""
    if not isinstance(mesh, Mesh) or mesh.axis_names != (AXIS,):
        raise ValueError(
            f"mesh = {mesh!r} is invalid: allowed a jax.sharding.Mesh with the one axis {AXIS!r} "
            "(jaxmpm.distributed.particle_mesh)"
        )
    return int(mesh.devices.size)


def to_host(tree: Any) -> Any:
    """Every array of `tree` as a NumPy array in this process. Arrays spread over several
    processes' devices (after `jax.distributed.initialize`) are gathered from all of them
    (`jax.experimental.multihost_utils.process_allgather`): every process must call this
    together. Other arrays are copied as they are."""

    def host(a):
        if isinstance(a, jax.Array) and not a.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(a, tiled=True))
        return np.asarray(a)

    return jax.tree.map(host, tree)


def padding_scale(dtype: DTypeLike) -> float:
    """Mass and volume of a padding copy relative to its twin: eps^2 of the dtype (1.4e-14 in
    float32, 4.9e-32 in float64), far below the round-off of any nodal sum the twin is part of,
    and far above the smallest normal number for any particle volume a scene has (a smaller
    scale would be flushed to zero in float32, giving the copy a density of 0 / 0)."""
    return float(np.finfo(dtype).eps) ** 2


@functools.lru_cache(maxsize=32)
def shard_order(scene: Scene, shards: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, pad): the sharded particle order, in which device j's block holds the j-th part of
    every phase (ceil(n / shards) particles of a phase of n), phase after phase. order (N',) gives
    the particle of the scene's order at each position; pad (N',) marks the copies that fill a
    phase up to a multiple of `shards` (copies of the phase's last particle)."""
    order, pad = [], []
    parts = []
    for sl in phase_slices(scene):
        n = sl.stop - sl.start
        c = -(-n // shards)
        idx = np.concatenate([np.arange(sl.start, sl.stop), np.full(c * shards - n, sl.stop - 1)])
        parts.append((idx.reshape(shards, c), (np.arange(c * shards) >= n).reshape(shards, c)))
    for j in range(shards):
        for idx, is_pad in parts:
            order.append(idx[j])
            pad.append(is_pad[j])
    return np.concatenate(order), np.concatenate(pad)


def _per_particle(state, fn_particle, fn_time):
    """Apply fn_particle to every per-particle leaf of a State (or history) and fn_time to t."""
    return State(
        **{
            name: (
                None
                if getattr(state, name) is None
                else (fn_time if name == "t" else fn_particle)(getattr(state, name))
            )
            for name in State.__dataclass_fields__
        }
    )


def state_spec(state: State) -> State:
    """PartitionSpecs of a State: particles split along 'particles', the time replicated."""
    return _per_particle(state, lambda a: P(AXIS), lambda a: P())


def to_shards(scene: Scene, state: State, mesh: Mesh) -> State:
    """The State in the sharded particle order, placed on the mesh (particles split, t replicated).
    Padding copies move exactly as their twins (all they gather is the same) and carry
    `padding_scale` of their mass and volume, so their share of every nodal sum is below round-off."""
    order, pad = shard_order(scene, mesh_size(mesh))
    permuted = _per_particle(state, lambda a: a[order], lambda a: a)
    scale = np.where(pad, padding_scale(permuted.mass.dtype), 1.0)
    permuted = dataclasses.replace(
        permuted,
        mass=permuted.mass * scale.astype(permuted.mass.dtype),
        volume=permuted.volume * scale.astype(permuted.volume.dtype),
    )
    specs = state_spec(state)
    return jax.tree.map(
        lambda a, s: jax.device_put(a, NamedSharding(mesh, s)), permuted, specs, is_leaf=lambda x: isinstance(x, P)
    )


def from_shards(scene: Scene, state: State, shards: int, time_axis: bool = False) -> State:
    """Back to the scene's particle order, padding dropped (a State, or a history with a leading
    time axis)."""
    order, pad = shard_order(scene, shards)
    real = np.flatnonzero(~pad)
    back = real[np.argsort(order[real])]
    take = (lambda a: a[:, back]) if time_axis else (lambda a: a[back])
    return _per_particle(state, take, lambda a: a)


def make_sharded_step(scene: Scene, mesh: Mesh) -> Callable[..., State]:
    """step(params, state, t_stop, dt) for a State in the sharded order on `mesh` (`to_shards`):
    `make_step` of one device's block under jax.shard_map. dt None: the CFL step."""
    shards = mesh_size(mesh)
    local = make_step(scene, shards=shards, axis_name=AXIS)
    shard_map = getattr(jax, "shard_map", None)
    if shard_map is None:  # jax < 0.6
        from jax.experimental.shard_map import shard_map

    def step(params, state, t_stop, dt=None):
        spec = state_spec(state)
        if dt is None:
            f = shard_map(lambda p, s, ts: local(p, s, ts), mesh=mesh, in_specs=(P(), spec, P()), out_specs=spec)
            return f(params, state, t_stop)
        f = shard_map(local, mesh=mesh, in_specs=(P(), spec, P(), P()), out_specs=spec)
        return f(params, state, t_stop, dt)

    return step
