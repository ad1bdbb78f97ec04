"""Restart files: a run driven by `simulate` on the host can save its state every few chunks and
be resumed later, bit-identical to an uninterrupted run.

A restart file (HDF5) holds the scene (TOML), every Params and State leaf, the outputs finished so
far and the driver's settings (t0, t_end, n_out, the next output, chunk length, fixed dt). It is
written to a temporary name and renamed, so a run killed mid-write leaves the previous restart
file intact and readable.
"""
from __future__ import annotations

import math
from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.io import _atomic
from jaxmpm.params import default_params
from jaxmpm.state import init_state


def _write_tree(group, tree):
    for i, leaf in enumerate(jax.tree.leaves(tree)):
        group.create_dataset(f"{i:04d}", data=np.asarray(leaf))


def _read_tree(group, like):
    leaves, treedef = jax.tree.flatten(like)
    if len(group) != len(leaves):
        raise ValueError(f"restart file: {group.name} has {len(group)} arrays, the scene needs {len(leaves)}")
    return jax.tree.unflatten(treedef, [jnp.asarray(group[f"{i:04d}"][()]) for i in range(len(leaves))])


def save(path, scene, params, state, history, *, t0, t_end, n_out, next_out, chunk, dt):
    """Write the restart file at `path` atomically. history: list of finished output States."""
    from jaxmpm import __version__
    from jaxmpm.scenefile import scene_to_toml

    with _atomic(Path(path)) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs.update({"jaxmpm_version": __version__, "t0": t0, "t_end": t_end, "n_out": n_out,
                            "next_out": next_out, "chunk": chunk, "dt": math.nan if dt is None else float(dt)})
            f.create_dataset("scene", data=scene_to_toml(scene))
            _write_tree(f.create_group("params"), params)
            _write_tree(f.create_group("state"), state)
            hist = f.create_group("history")
            for k, s in enumerate(history):
                _write_tree(hist.create_group(f"{k:04d}"), s)


def load(path) -> dict:
    """Read a restart file: {scene, params, state, history, t0, t_end, n_out, next_out, chunk, dt}."""
    from jaxmpm.scenefile import scene_from_toml

    with h5py.File(path, "r") as f:
        scene = scene_from_toml(f["scene"].asstr()[()], str(path))
        like_params = default_params(scene, dtype=f["params/0000"].dtype)
        params = _read_tree(f["params"], like_params)
        like_state = init_state(scene, like_params)
        state = _read_tree(f["state"], like_state)
        history = [_read_tree(f["history"][k], like_state) for k in sorted(f["history"])]
        a = dict(f.attrs)
    dt = None if math.isnan(a["dt"]) else a["dt"]
    return dict(scene=scene, params=params, state=state, history=history, t0=float(a["t0"]), t_end=float(a["t_end"]),
                n_out=int(a["n_out"]), next_out=int(a["next_out"]), chunk=int(a["chunk"]), dt=dt)


def resume(path, *, progress=True, restart_every=None):
    """Continue the run saved in restart file `path` to its end; returns (scene, params, final,
    history) as `simulate` would have. restart_every: keep saving every so many chunks."""
    from jaxmpm.simulate import _host_driver

    r = load(path)
    dt = None if r["dt"] is None else jnp.asarray(r["dt"], r["state"].t.dtype)
    final, history = _host_driver(r["scene"], r["params"], r["state"], r["t_end"], r["n_out"], dt, progress, r["chunk"],
                                  t0=r["t0"], history=r["history"], start_out=r["next_out"],
                                  restart_file=path if restart_every else None, restart_every=restart_every or 0)
    return r["scene"], r["params"], final, history
