"""Output: HDF5 snapshots with an XDMF index for ParaView, and text summaries (PNG plots:
`jaxmpm.io.plot.plot_state`, also `jaxmpm.io.plot_state`; safe writing: `jaxmpm.io.files`).

HDF5 layout written by `write` (SI units; every dataset carries a `units` attribute):

    /                    attrs: jaxmpm_version, dtype, dim, n_out (outputs after the first),
                                n_times, scene_name, phases
    /scene               the scene as TOML text (`jaxmpm.scene_to_toml`): how to reproduce the run
    /params/<key path>   each Params leaf, e.g. /params/phases/disk_a/E (only if params given)
    /t0000, /t0001, ...  one group per output time, attr `time` (s)
    /tNNNN/<phase>/      attrs: material, field, n_particles
        x (n, d) m, v (n, d) m/s, volume (n,) m^3, mass (n,) kg (per unit depth in 2D: m^2, kg/m;
        per unit area in 1D: m, kg/m^2; per radian in axisymmetric scenes: m^3/rad, kg/rad),
        F (n, D, D) 1, stress (n, D, D) Pa (D = d, or 3 in axisymmetric scenes: r, z, theta),
        energy (n,) J/kg; C (n, d, d) 1/s with APIC transfer;
        eps_ps (n,) 1, pressure (n,) Pa and damage (n,) 1 where the State has them;
        x3 (n, 3) m and v3 (n, 3) m/s: x and v padded with zeros to 3 components (1D, 2D), for XDMF.

The XDMF file beside it (same stem, .xdmf) is a temporal collection of spatial collections, one
Polyvertex grid per phase, whose data items point into the HDF5 file by relative name: open the
.xdmf in ParaView (Xdmf3 reader). Files are never overwritten unless asked (`overwrite=True`,
the command line's `--overwrite`), a directory never, and are written to a temporary name then
renamed (the .h5 before the .xdmf), so an interrupted write never leaves a half file under the
final name. `read` and `summary` check the layout: a file that is not one `write` wrote gets a
ValueError naming it and what is missing.
"""

# longer than 400 lines on purpose: the HDF5/XDMF layout's writer and reader side by side (write, read and summary
# share its names and checks) below the docstring that documents the layout

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import h5py
import jax
import numpy as np

from jaxmpm.io.plot import plot_state  # noqa: F401  (io's API: jaxmpm.io.plot_state)
from jaxmpm.io.files import atomic_write, make_parent, check_new, check_space  # noqa: F401  (io's API; restart, cli)
from jaxmpm.io.schema import FIELDS, OPTIONAL, UNITS, check_scene, check_shapes, field_shapes, units  # noqa: F401  (io's API)
from jaxmpm.io.scenefile import parse_toml, scene_from_dict, scene_to_toml
from jaxmpm.model.state import State, phase_slices
from jaxmpm.version import __version__
from jaxmpm.model.params import Params
from jaxmpm.model.scene import Scene

H5_SUFFIXES = (".h5", ".hdf5")


# ----------------------------------------------------------------------------------- safe writing
def estimate_bytes(scene: Scene, n_particles: int, n_times: int, itemsize: int) -> int:
    """Bytes that `write` needs for n_times outputs of n_particles (datasets x, v, x3, v3, volume,
    mass, F, stress, energy, eps_ps, pressure, damage, C where used), with 10% for metadata and the XDMF."""
    d = scene.dim
    D = 3 if scene.axisymmetric else d  # F and stress: (n, 3, 3) in axisymmetric scenes
    per_particle = 2 * d + 6 + 2 + 2 * D * D + 4 + (d * d if scene.transfer == "apic" else 0)
    return int(1.1 * n_times * n_particles * per_particle * itemsize) + 65536


def xdmf_path(path: str | os.PathLike) -> Path:
    """The XDMF file written beside the HDF5 file `path` (same stem, suffix .xdmf)."""
    return Path(path).with_suffix(".xdmf")


def _h5_path(path) -> Path:
    path = Path(path)
    if path.suffix not in H5_SUFFIXES:
        raise ValueError(
            f"path = {os.fspath(path)!r} is invalid: allowed a file name ending in {' or '.join(H5_SUFFIXES)}"
        )
    return path


# ----------------------------------------------------------------------------------- write
def _host_history(history: State) -> dict:
    """{field: numpy array with a leading time axis} of a history (or of one State)."""
    if not isinstance(history, State):
        raise ValueError(
            f"history = {type(history).__name__} is invalid: allowed a jaxmpm.State (one State, or a "
            "history with a leading time axis as from jaxmpm.simulate)"
        )
    x = np.asarray(history.x)
    if x.ndim == 2:
        history = jax.tree.map(lambda a: np.asarray(a)[None], history)
    elif x.ndim != 3:
        raise ValueError(
            f"history.x has shape {x.shape}: allowed (n_times, n_particles, dim) or one State's "
            "(n_particles, dim); write each member of a vmapped ensemble separately"
        )
    out = {"t": np.asarray(history.t).reshape(-1)}
    for name in FIELDS + OPTIONAL:
        a = getattr(history, name, None)
        if a is not None:
            out[name] = np.asarray(a)
    return out


def _key_path(path) -> str:
    parts = []
    for k in path:
        for attr in ("name", "key", "idx"):
            if hasattr(k, attr):
                parts.append(str(getattr(k, attr)))
                break
        else:
            parts.append(str(k))
    return "/".join(parts)


def _pad3(a: np.ndarray) -> np.ndarray:
    return np.concatenate([a, np.zeros(a.shape[:-1] + (3 - a.shape[-1],), a.dtype)], axis=-1)


def write(
    path: str | os.PathLike, scene: Scene, history: State, params: Params | None = None, overwrite: bool = False
) -> tuple[Path, Path]:
    """Write `history` (a State with a leading time axis, as from `jaxmpm.simulate`; or one State)
    to the HDF5 file `path` (.h5) and an XDMF index beside it. Returns (h5 path, xdmf path).

    params: optional Params, stored under /params. Raises FileExistsError if either file exists
    and not `overwrite`, if either is a directory, or if a folder of `path` is a file; ValueError
    if the history is not a State or any of its fields does not fit the scene.
    """
    # longer than 60 lines on purpose: the file's groups and datasets written one after another, in the file's
    # order
    h5 = _h5_path(path)
    xdmf = xdmf_path(h5)
    check_new(h5, xdmf, overwrite=overwrite)  # and neither is a directory, even with overwrite
    check_scene(scene)
    data = _host_history(history)
    slices = phase_slices(scene)
    n, d = data["x"].shape[1], data["x"].shape[2]
    if n != slices[-1].stop or d != scene.dim:
        raise ValueError(
            f"history has {n} particles in {d}D: the scene {scene.name!r} has "
            f"{slices[-1].stop} particles in {scene.dim}D"
        )
    n_times = data["x"].shape[0]
    if data["t"].shape != (n_times,) or data["t"].dtype.kind != "f":
        raise ValueError(
            f"history.t has shape {np.shape(history.t)} and dtype {data['t'].dtype}: the history has "
            f"{n_times} output times (history.x has shape {data['x'].shape}) and needs ({n_times},) "
            "floating-point times (s)"
        )
    check_shapes(scene, data, "history", (n_times,))
    make_parent(h5)
    # both renamed only once both are written, the .h5 first: should that rename fail, no new
    # .xdmf points into a file that is not there
    with atomic_write(xdmf) as tmp_xdmf, atomic_write(h5) as tmp_h5:
        with h5py.File(tmp_h5, "w") as f:
            f.attrs.update(
                {
                    "jaxmpm_version": __version__,
                    "dtype": str(data["x"].dtype),
                    "dim": d,
                    "n_out": len(data["t"]) - 1,
                    "n_times": len(data["t"]),
                    "scene_name": scene.name,
                    "phases": ",".join(scene.phase_names()),
                }
            )
            f.create_dataset("scene", data=scene_to_toml(scene))
            if params is not None:
                for kp, leaf in jax.tree_util.tree_flatten_with_path(params)[0]:
                    ds = f.create_dataset(f"params/{_key_path(kp)}", data=np.asarray(leaf))
                    ds.attrs["key"] = jax.tree_util.keystr(kp)
            for i, t in enumerate(data["t"]):
                group = f.create_group(f"t{i:04d}")
                group.attrs["time"] = t
                for phase, sl in zip(scene.phases, slices):
                    pg = group.create_group(phase.name)
                    pg.attrs.update(
                        {
                            "material": phase.to_dict()["material"],
                            "field": phase.field,
                            "n_particles": sl.stop - sl.start,
                        }
                    )
                    for name in FIELDS + OPTIONAL:
                        if name in data:
                            pg.create_dataset(name, data=data[name][i, sl]).attrs["units"] = units(
                                name, d, scene.axisymmetric
                            )
                    if d < 3:
                        pg.create_dataset("x3", data=_pad3(data["x"][i, sl])).attrs["units"] = "m"
                        pg.create_dataset("v3", data=_pad3(data["v"][i, sl])).attrs["units"] = "m/s"
        Path(tmp_xdmf).write_text(_xdmf_text(h5.name, scene, data, slices), encoding="utf-8")
    return h5, xdmf


def _xdmf_text(h5_name: str, scene, data: dict, slices) -> str:
    d = scene.dim

    def item(dims, ref):
        prec = data[ref.rsplit("/", 1)[1].rstrip("3")].dtype.itemsize
        return (
            f'<DataItem Dimensions="{" ".join(map(str, dims))}" NumberType="Float" Precision="{prec}" '
            f'Format="HDF">{escape(h5_name)}:{ref}</DataItem>'
        )

    lines = [
        '<?xml version="1.0" ?>',
        '<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>',
        '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">',
        "<Domain>",
        f'<Grid Name={quoteattr(scene.name)} GridType="Collection" CollectionType="Temporal">',
    ]
    for i, t in enumerate(data["t"]):
        grp = f"/t{i:04d}"
        lines += [
            f'  <Grid Name="t{i:04d}" GridType="Collection" CollectionType="Spatial">',
            f'    <Time Value="{float(t)!r}"/>',
        ]
        for phase, sl in zip(scene.phases, slices):
            n, base = sl.stop - sl.start, f"{grp}/{phase.name}"
            pos = "x3" if d < 3 else "x"
            vel = "v3" if d < 3 else "v"
            lines += [
                f'    <Grid Name="{phase.name}" GridType="Uniform">',
                f'      <Topology TopologyType="Polyvertex" NumberOfElements="{n}" NodesPerElement="1"/>',
                f'      <Geometry GeometryType="XYZ">{item((n, 3), f"{base}/{pos}")}</Geometry>',
                f'      <Attribute Name="v" AttributeType="Vector" Center="Node">{item((n, 3), f"{base}/{vel}")}</Attribute>',
            ]
            for name in ("volume", "mass", "energy") + tuple(k for k in ("eps_ps", "pressure", "damage") if k in data):
                lines.append(
                    f'      <Attribute Name="{name}" AttributeType="Scalar" Center="Node">'
                    f"{item((n,), f'{base}/{name}')}</Attribute>"
                )
            md = scene.material_dim
            names = "rzt" if scene.axisymmetric else "xyz"  # axisymmetric: r, z, theta (hoop)
            for a in range(md):
                for b in range(a, md):
                    slab = (
                        f'<DataItem ItemType="HyperSlab" Dimensions="{n} 1 1" Type="HyperSlab">'
                        f'<DataItem Dimensions="3 3" Format="XML">0 {a} {b} 1 1 1 {n} 1 1</DataItem>'
                        f"{item((n, md, md), f'{base}/stress')}</DataItem>"
                    )
                    lines.append(
                        f'      <Attribute Name="stress_{names[a]}{names[b]}" AttributeType="Scalar" '
                        f'Center="Node">{slab}</Attribute>'
                    )
            lines.append("    </Grid>")
        lines.append("  </Grid>")
    lines += ["</Grid>", "</Domain>", "</Xdmf>"]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------- read
def open_h5(path: str | os.PathLike, what: str = "jaxmpm output file (written by jaxmpm.io.write)") -> h5py.File:
    """Open the HDF5 file `path` for reading: FileNotFoundError if it does not exist, ValueError
    naming the path if it is a directory or not a readable HDF5 file (text, truncated, ...)."""
    path = Path(path)
    if not os.path.lexists(path) or (path.is_symlink() and not path.exists()):
        raise FileNotFoundError(f"{os.fspath(path)} does not exist")
    if path.is_dir():
        raise ValueError(f"{os.fspath(path)} is a directory: allowed a {what}")
    try:
        return h5py.File(path, "r")
    except OSError as e:
        raise ValueError(f"{os.fspath(path)} is not a readable HDF5 file ({e}): allowed a {what}") from None


def _is_restart(f) -> bool:
    return "state" in f and "history" in f and "t0" in f.attrs


def _open(path):
    f = open_h5(path)
    try:
        if _is_restart(f):
            raise ValueError(
                f"{os.fspath(path)} is a jaxmpm restart file, not an output file: continue its run with "
                "jaxmpm.restart.resume (jaxmpm run --resume FOLDER)"
            )
        if "scene" not in f or not isinstance(f["scene"], h5py.Dataset) or f["scene"].dtype.kind not in "OSU":
            raise ValueError(f"{os.fspath(path)} is not a jaxmpm output file: it has no /scene dataset (TOML text)")
        if not _times(f):
            raise ValueError(
                f"{os.fspath(path)} holds no output time group /t0000: it is not a complete jaxmpm output file"
            )
    except BaseException:
        f.close()
        raise
    return f


def _times(f) -> list[str]:
    return sorted((k for k in f if k.startswith("t") and k[1:].isdigit()), key=lambda k: int(k[1:]))


def _node(f, path, ref: str, kind=h5py.Dataset):
    """f[ref], a dataset (or group: kind=h5py.Group); ValueError naming the file if it is missing."""
    node = f.get(ref)
    if not isinstance(node, kind):
        noun = "group" if kind is h5py.Group else "dataset"
        raise ValueError(f"{os.fspath(path)} has no {noun} {ref}: it is not a complete jaxmpm output file")
    return node


def _time(f, path, group: str):
    """The attribute `time` (s) of the output group /`group`, as stored; ValueError naming the file if
    it is missing or not a number."""
    group = _node(f, path, f"/{group}", h5py.Group)
    if "time" not in group.attrs:
        raise ValueError(
            f"{os.fspath(path)} has no attribute 'time' on {group.name}: it is not a complete jaxmpm output file"
        )
    t = group.attrs["time"]
    if np.ndim(t) != 0 or np.asarray(t).dtype.kind not in "fiu":
        raise ValueError(f"{os.fspath(path)}: {group.name} attribute time = {t!r} is invalid: allowed a number (s)")
    return t


def _scene_text(f, path) -> str:
    try:
        return f["scene"].asstr()[()]
    except (TypeError, ValueError, OSError) as e:
        raise ValueError(f"{os.fspath(path)}:/scene is not TOML text ({e})") from None


def read(path: str | os.PathLike) -> tuple[Scene, State]:
    """Read a file written by `write`: returns (scene, history), history a State of numpy arrays
    with a leading time axis (t (n_times,) s; x (n_times, N, d) m; ...), phases in scene order.
    FileNotFoundError if `path` does not exist; ValueError naming the file and what is missing
    or wrong if it is not a complete output file (or does not fit its own /scene)."""
    where = os.fspath(path)
    with _open(path) as f:
        try:
            scene = scene_from_dict(parse_toml(_scene_text(f, path), f"{where}:/scene"))
        except ValueError as e:
            raise ValueError(e if str(e).startswith(where) else f"{where}:/scene: {e}") from None
        slices = phase_slices(scene)
        shapes = field_shapes(scene)
        groups = _times(f)
        t = np.array([_time(f, path, group) for group in groups])
        for group in groups:
            for p in scene.phases:
                _node(f, path, f"/{group}/{p.name}", h5py.Group)
        first = f[groups[0]][scene.phases[0].name]
        fields = {}
        for name in FIELDS + OPTIONAL:
            if name not in FIELDS and name not in first:
                continue
            per_time = []
            for group in groups:
                parts = []
                for p, sl in zip(scene.phases, slices):
                    ds = _node(f, path, f"/{group}/{p.name}/{name}")
                    need = (sl.stop - sl.start,) + shapes[name][1:]
                    if ds.shape != need or ds.dtype.kind != "f":
                        raise ValueError(
                            f"{where}:/{group}/{p.name}/{name} has shape {ds.shape} ({ds.dtype}): its scene "
                            f"needs {need} floating-point numbers"
                        )
                    parts.append(ds[()])
                per_time.append(np.concatenate(parts))
            fields[name] = np.stack(per_time)
    names = {fl.name for fl in dataclasses.fields(State)}
    history = State(t=t, **{k: v for k, v in fields.items() if k in names})
    return scene, history


# ----------------------------------------------------------------------------------- plots, summaries
def summary(path: str | os.PathLike) -> str:
    """Text summary of a file written by `write`: scene, output times, phases with particle counts,
    total mass and kinetic energy at the first and last output. Errors as `read`."""
    where = os.fspath(path)
    with _open(path) as f:
        a = f.attrs
        spec = parse_toml(_scene_text(f, path), f"{where}:/scene")
        groups = _times(f)
        try:
            dim = int(a["dim"]) if "dim" in a else len(spec["grid"]["cells"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{where} has no dimension: neither an attribute 'dim' nor grid.cells in /scene") from None
        times = [float(_time(f, path, group)) for group in groups]
        phases = str(a["phases"]).split(",") if "phases" in a else list(_node(f, path, f"/{groups[0]}", h5py.Group))
        for group in groups:
            for p in phases:
                _node(f, path, f"/{group}/{p}", h5py.Group)
        for group in (groups[0], groups[-1]):
            for p in phases:
                for name in ("x", "v", "mass"):
                    _node(f, path, f"/{group}/{p}/{name}")
        rows = []
        try:
            for group in (groups[0], groups[-1]):
                m = sum(float(np.sum(f[group][p]["mass"][()])) for p in phases)
                ke = sum(
                    float(0.5 * np.sum(f[group][p]["mass"][()] * np.sum(f[group][p]["v"][()] ** 2, -1))) for p in phases
                )
                rows.append((m, ke))
        except (TypeError, ValueError) as e:
            raise ValueError(
                f"{where}: the masses or velocities of /{group} are not numbers of matching shapes ({e})"
            ) from None
        lines = [
            f"file:    {os.fspath(path)} (jaxmpm {a.get('jaxmpm_version', '?')}, {a.get('dtype', '?')}, {dim}D)",
            f"scene:   {spec.get('name', '?')}" + (f": {spec['description']}" if spec.get("description") else ""),
            f"outputs: {len(times)} times from {times[0]:.6g} s to {times[-1]:.6g} s",
            "phases:",
        ]
        for p in phases:
            pa = f[groups[0]][p].attrs
            lines.append(
                f"  {p:<20} material {str(pa.get('material', '?')):<20} field {int(pa.get('field', 0))}  "
                f"{f[groups[0]][p]['x'].shape[0]} particles"
            )
        if "params" in f:
            lines.append("params:  stored under /params")
    axi = bool(spec.get("axisymmetric", False))
    mass_u = units("mass", dim, axi)
    lines += [
        f"{'':<22}{'first':>14}{'last':>14}",
        f"{'t (s)':<22}{times[0]:>14.6g}{times[-1]:>14.6g}",
        f"{'total mass (' + mass_u + ')':<22}{rows[0][0]:>14.6g}{rows[1][0]:>14.6g}",
        f"{'kinetic (' + units('kinetic', dim, axi) + ')':<22}{rows[0][1]:>14.6g}{rows[1][1]:>14.6g}",
    ]
    return "\n".join(lines)
