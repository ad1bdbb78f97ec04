"""Restart files: a run driven by `simulate` on the host can save its state every few chunks and
be resumed later, bit-identical to an uninterrupted run.

A restart file (HDF5) holds the scene (TOML), every Params and State leaf, the outputs finished so
far and the driver's settings (t0, t_end, n_out, the next output, chunk length, fixed dt). A run's
first save writes it to a temporary name and renames it (a run killed mid-write leaves any earlier
file intact); its later saves (`save(..., append=True)`) add the outputs finished since and
overwrite the state in place, so a save costs what is new, not the whole history again. The host
driver defers SIGINT (and, under `jaxmpm run`, SIGTERM) while it runs, so a save is never cut
short by them; SIGKILL or a power cut during one of these in-place saves (milliseconds) can leave
the file unreadable, as HDF5 writes are not transactions.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.io import open_h5
from jaxmpm.io.files import atomic_write
from jaxmpm.io.scenefile import parse_toml, scene_from_dict, scene_to_toml
from jaxmpm.model.params import Params, check_params, default_params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, check_state, init_state
from jaxmpm.run.driver import host_driver, stack_states
from jaxmpm.version import __version__

WHAT = "jaxmpm restart file (<name>.restart.h5, saved by jaxmpm.simulate(restart_file=...))"
DRIVER = ("t0", "t_end", "n_out", "next_out", "chunk", "dt")


def _incomplete(path, why: str) -> ValueError:
    return ValueError(f"{os.fspath(path)} is not a complete {WHAT}: {why}")


def _write_tree(group, tree):
    for i, leaf in enumerate(jax.tree.leaves(tree)):
        group.create_dataset(f"{i:04d}", data=np.asarray(leaf))


def _read_tree(group, like, path, what: str):
    """The tree `like` with its leaves read from `group` (datasets 0000, 0001, ... in leaf order);
    ValueError naming the file, the dataset and the leaf where one is missing or its shape or dtype
    is not the one of `like` (built from the scene in the file)."""
    flat, treedef = jax.tree_util.tree_flatten_with_path(like)
    counts = (
        f"{group.name} holds {len(group)} arrays, the scene in the file needs {len(flat)} "
        f"({', '.join(what + jax.tree_util.keystr(k) for k, _ in flat)})"
    )
    for i, (kp, _leaf) in enumerate(flat):
        if not isinstance(group.get(f"{i:04d}"), h5py.Dataset):
            raise _incomplete(
                path, f"it has no dataset {group.name}/{i:04d} ({what + jax.tree_util.keystr(kp)}): {counts}"
            )
    if len(group) != len(flat):
        raise ValueError(f"{os.fspath(path)}: {counts}")
    leaves = []
    for i, (kp, leaf) in enumerate(flat):
        ds = group[f"{i:04d}"]
        name = what + jax.tree_util.keystr(kp)
        if ds.shape != leaf.shape or ds.dtype != leaf.dtype:
            raise ValueError(
                f"{os.fspath(path)}:{group.name}/{i:04d} ({name}) has shape {ds.shape} and dtype "
                f"{ds.dtype}: the scene in the file (/scene) needs shape {leaf.shape} and dtype {leaf.dtype}"
            )
        leaves.append(jnp.asarray(ds[()]))
    return jax.tree.unflatten(treedef, leaves)


def _append(path, state, history, next_out) -> bool:
    """Bring the restart file at `path`, an earlier save of this run, up to date in place: the
    outputs of `history` it lacks, the state (overwritten; same shapes and dtypes), next_out.
    False, with nothing written, where the file is not such a save (missing, another layout)."""
    path = Path(path)
    if not path.is_file():
        return False
    leaves = [np.asarray(a) for a in jax.tree.leaves(state)]
    with h5py.File(path, "r+") as f:
        state_group, history_group = f.get("state"), f.get("history")
        if not (isinstance(state_group, h5py.Group) and isinstance(history_group, h5py.Group)) or len(
            state_group
        ) != len(leaves):
            return False
        done = len(history_group)
        if done > len(history) or (done and f"{done - 1:04d}" not in history_group):
            return False
        datasets = [state_group.get(f"{i:04d}") for i in range(len(leaves))]
        if not all(
            isinstance(d, h5py.Dataset) and d.shape == a.shape and d.dtype == a.dtype for d, a in zip(datasets, leaves)
        ):
            return False
        for k in range(done, len(history)):
            _write_tree(history_group.create_group(f"{k:04d}"), history[k])
        for d, a in zip(datasets, leaves):
            d.write_direct(np.ascontiguousarray(a))
        f.attrs["next_out"] = next_out
        f.flush()
    return True


def save(
    path: str | os.PathLike,
    scene: Scene,
    params: Params,
    state: State,
    history: Sequence[State],
    *,
    t0: float,
    t_end: float,
    n_out: int,
    next_out: int,
    chunk: int,
    dt: float | None,
    append: bool = False,
) -> None:
    """Write the restart file at `path`. history: list of finished output States; t0, t_end (s):
    the run's start and end; n_out, next_out: its outputs and the next one due; chunk: steps per
    chunk; dt: the fixed step (s) or None (the CFL step). append=False: the whole file, written
    atomically (a temporary name renamed). append=True: `path` is an earlier save of this same run
    (same scene, params and driver settings, a prefix of `history`): only the outputs it lacks and
    the state are written, in place (the whole file where `path` is not such a save)."""
    if append and _append(path, state, history, next_out):
        return

    with atomic_write(Path(path)) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs.update(
                {
                    "jaxmpm_version": __version__,
                    "t0": t0,
                    "t_end": t_end,
                    "n_out": n_out,
                    "next_out": next_out,
                    "chunk": chunk,
                    "dt": math.nan if dt is None else float(dt),
                }
            )
            f.create_dataset("scene", data=scene_to_toml(scene))
            _write_tree(f.create_group("params"), params)
            _write_tree(f.create_group("state"), state)
            history_group = f.create_group("history")
            for k, s in enumerate(history):
                _write_tree(history_group.create_group(f"{k:04d}"), s)


def _open(path):
    """The restart file open for reading, its layout checked: /scene text, groups /params, /state,
    /history and the driver's attributes (ValueError naming the path and what is missing)."""
    f = open_h5(path, WHAT)
    try:
        if "t0" not in f.attrs and "state" not in f and any(k.startswith("t") and k[1:].isdigit() for k in f):
            raise ValueError(
                f"{os.fspath(path)} is a jaxmpm output file, not a restart file: read it with "
                "jaxmpm.io.read; a run resumes from its <name>.restart.h5"
            )
        scene = f.get("scene")
        if not isinstance(scene, h5py.Dataset) or scene.dtype.kind not in "OSU":
            raise _incomplete(path, "it has no /scene dataset (TOML text)")
        for name in ("params", "state", "history"):
            if not isinstance(f.get(name), h5py.Group):
                raise _incomplete(path, f"it has no group /{name}")
        for name in DRIVER:
            if name not in f.attrs:
                raise _incomplete(path, f"it has no attribute {name!r} (allowed attributes {', '.join(DRIVER)})")
    except BaseException:
        f.close()
        raise
    return f


def _dtypes(f, path):
    """(params dtype, state dtype): those of /params/0000 and /state/0000 (state.t), float32 or float64."""
    out = []
    for group in ("params", "state"):
        ds = f[group].get("0000")
        if not isinstance(ds, h5py.Dataset):
            raise _incomplete(path, f"it has no dataset /{group}/0000")
        if ds.dtype not in (np.float32, np.float64):
            raise ValueError(f"{os.fspath(path)}:/{group}/0000 has dtype {ds.dtype}: allowed float32 or float64")
        out.append(ds.dtype)
    return tuple(out)


def dtype(path: str | os.PathLike) -> np.dtype:
    """The floating-point dtype (float32 or float64) of the run saved in the restart file `path`:
    with float64, enable 64-bit JAX (jax.config.update('jax_enable_x64', True)) before `load`.
    FileNotFoundError if it does not exist; ValueError naming it if it is not a restart file."""
    with _open(path) as f:
        return np.result_type(*_dtypes(f, path))


def _number(a, path, name, integer=False):
    v = a[name]
    try:
        ok = np.ndim(v) == 0 and np.asarray(v).dtype.kind in "fiu"
        x = float(v) if ok else math.nan
    except (TypeError, ValueError):
        ok = False
    if not ok or (integer and not (math.isfinite(x) and x == int(x))):
        shown = v.tolist() if isinstance(v, (np.ndarray, np.generic)) else v
        raise ValueError(
            f"{os.fspath(path)}: attribute {name} = {shown!r} is invalid: allowed "
            f"{'an integer' if integer else 'a number'}"
        )
    return int(x) if integer else x


def _driver(a, path) -> dict:
    """The driver's attributes, checked: t0 < t_end both finite, n_out >= 1, 0 <= next_out <=
    n_out, chunk >= 1, dt NaN (the CFL step) or finite > 0."""
    where = os.fspath(path)
    r = {k: _number(a, path, k, integer=k in ("n_out", "next_out", "chunk")) for k in DRIVER}
    if not math.isfinite(r["t0"]):
        raise ValueError(f"{where}: attribute t0 = {r['t0']!r} is invalid: allowed a finite time (s)")
    if not (math.isfinite(r["t_end"]) and r["t_end"] > r["t0"]):
        raise ValueError(
            f"{where}: attribute t_end = {r['t_end']!r} is invalid: allowed a finite time > t0 = {r['t0']!r} s"
        )
    if r["n_out"] < 1:
        raise ValueError(f"{where}: attribute n_out = {r['n_out']} is invalid: allowed an integer >= 1")
    if not 0 <= r["next_out"] <= r["n_out"]:
        raise ValueError(
            f"{where}: attribute next_out = {r['next_out']} is invalid: allowed an integer in [0, n_out = {r['n_out']}]"
        )
    if r["chunk"] < 1:
        raise ValueError(f"{where}: attribute chunk = {r['chunk']} is invalid: allowed an integer >= 1 (steps)")
    if not (math.isnan(r["dt"]) or (math.isfinite(r["dt"]) and r["dt"] > 0)):
        raise ValueError(
            f"{where}: attribute dt = {r['dt']!r} is invalid: allowed a finite time step > 0 s, or NaN (the CFL step)"
        )
    r["dt"] = None if math.isnan(r["dt"]) else r["dt"]
    return r


def _read_scene(f: h5py.File, path: str | os.PathLike) -> Scene:
    """The Scene of a restart file's /scene (TOML text); ValueError naming the file where it is not
    TOML text or not a valid scene."""
    where = os.fspath(path)
    try:
        text = f["scene"].asstr()[()]
    except (TypeError, ValueError, OSError) as e:
        raise _incomplete(path, f"/scene is not TOML text ({e})") from None
    try:
        return scene_from_dict(parse_toml(text, f"{where}:/scene"))
    except ValueError as e:
        raise ValueError(e if str(e).startswith(where) else f"{where}:/scene: {e}") from None


def load(path: str | os.PathLike) -> dict:
    """Read a restart file: {scene, params, state, history, t0, t_end, n_out, next_out, chunk, dt}.

    FileNotFoundError if `path` does not exist. ValueError naming the file and what is wrong if it
    is not a readable HDF5 file or not a complete restart file, if an array's shape or dtype does
    not fit the scene stored in it, if its params or state are out of range (`check_params`,
    `check_state`), or if a driver attribute is out of range (t0 < t_end, both finite; n_out >= 1;
    0 <= next_out <= n_out; chunk >= 1; dt > 0 or NaN); with float64 arrays, when 64-bit JAX is off.
    """
    where = os.fspath(path)
    with _open(path) as f:
        scene = _read_scene(f, path)
        drv = _driver(f.attrs, path)
        p_dtype, s_dtype = _dtypes(f, path)
        if np.float64 in (p_dtype, s_dtype) and not jax.config.jax_enable_x64:
            raise ValueError(
                f"{where} holds float64 arrays: enable 64-bit JAX before loading it "
                "(jax.config.update('jax_enable_x64', True); `jaxmpm run --resume` does this itself)"
            )
        params = _read_tree(f["params"], default_params(scene, dtype=p_dtype), path, "params")
        like_state = init_state(scene, default_params(scene, dtype=s_dtype))
        state = _read_tree(f["state"], like_state, path, "state")
        keys = sorted(f["history"])
        if keys != [f"{k:04d}" for k in range(len(keys))] or not all(
            isinstance(f["history"][k], h5py.Group) for k in keys
        ):
            raise _incomplete(
                path,
                f"/history holds {keys[:5]}{'...' if len(keys) > 5 else ''}: allowed groups "
                "0000, 0001, ... (the outputs done)",
            )
        history = [_read_tree(f["history"][k], like_state, path, "state") for k in keys]
    if len(history) != drv["next_out"] + 1:
        raise ValueError(
            f"{where}: /history holds {len(history)} states: attribute next_out = {drv['next_out']} "
            f"needs {drv['next_out'] + 1} (the initial state and each output done)"
        )
    try:
        check_params(scene, params)
    except ValueError as e:
        raise ValueError(f"{where}:/params: {e}") from None
    for label, s in (("/state", state), *((f"/history/{k}", h) for k, h in zip(keys, history))):
        try:
            check_state(scene, s)
        except ValueError as e:
            raise ValueError(f"{where}:{label}: {e}") from None
    t = float(state.t)
    slack = 8 * float(jnp.finfo(state.t.dtype).eps) * max(abs(drv["t_end"]), drv["t_end"] - drv["t0"], abs(drv["t0"]))
    if not drv["t0"] - slack <= t <= drv["t_end"] + slack:
        raise ValueError(
            f"{where}: state.t = {t!r} s lies outside the run [t0, t_end] = [{drv['t0']!r}, "
            f"{drv['t_end']!r}] s of the attributes t0 and t_end"
        )
    return dict(scene=scene, params=params, state=state, history=history, **drv)


def resume(
    path: str | os.PathLike, *, progress: bool = True, restart_every: int | None = None
) -> tuple[Scene, Params, State, State]:
    """Continue the run saved in restart file `path` to its end; returns (scene, params, final,
    history) as `simulate` would have (of a complete run, its saved results, with nothing run).
    restart_every: keep saving every so many chunks."""
    if not (restart_every is None or (isinstance(restart_every, (int, np.integer)) and restart_every >= 0)):
        raise ValueError(
            f"restart_every = {restart_every!r} is invalid: allowed None or an integer >= 0 "
            "(chunks; 0 or None: do not save)"
        )
    r = load(path)
    if r["next_out"] == r["n_out"]:  # the run is complete: its results, nothing to run
        return r["scene"], r["params"], r["state"], stack_states(r["history"])
    dt = None if r["dt"] is None else jnp.asarray(r["dt"], r["state"].t.dtype)
    final, history = host_driver(
        r["scene"],
        r["params"],
        r["state"],
        r["t_end"],
        r["n_out"],
        dt,
        progress,
        r["chunk"],
        t0=r["t0"],
        history=r["history"],
        start_out=r["next_out"],
        restart_file=path if restart_every else None,
        restart_every=restart_every or 0,
        restart_saved=True,
        write_restart=save,
    )
    return r["scene"], r["params"], final, history
