"""PNG plots of a State (`plot_state`, also `jaxmpm.io.plot_state`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from jaxmpm import diagnostics
from jaxmpm.io.files import atomic_write, check_new
from jaxmpm.io.schema import check_scene, check_shapes, units
from jaxmpm.model.params import Params, default_params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, phase_slices

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn
    from matplotlib.figure import Figure


def plot_state(scene: Scene, state: State, path: str | os.PathLike, overwrite: bool = False) -> Path:
    """PNG of one State (no time axis), particles coloured by phase: 2D a scatter of x, 1D velocity
    and stress against position, 3D the projection on the x-y plane; in 2D and 3D a second panel
    coloured by damage where any particle is damaged (the crack pattern). Returns the path.
    Raises FileExistsError if `path` exists and not `overwrite` (or is a directory); ValueError if
    `path` does not end in .png or the state does not fit the scene."""
    # longer than 60 lines on purpose: one figure drawn top to bottom (matplotlib calls on shared axes)
    from matplotlib.figure import Figure  # matplotlib loaded only when a figure is drawn (its import is slow)

    path = Path(path)
    if path.suffix != ".png":
        raise ValueError(f"path = {os.fspath(path)!r} is invalid: allowed a file name ending in .png")
    check_new(path, overwrite=overwrite)  # and it is not a directory, even with overwrite
    check_scene(scene)
    if not isinstance(state, State):
        raise ValueError(
            f"state = {type(state).__name__} is invalid: allowed a jaxmpm.State (one State, e.g. "
            "jax.tree.map(lambda a: a[-1], history))"
        )
    x = np.asarray(state.x)
    if x.ndim != 2:
        raise ValueError(f"state.x has shape {x.shape}: plot one State, e.g. jax.tree.map(lambda a: a[-1], history)")
    n = phase_slices(scene)[-1].stop
    if x.shape != (n, scene.dim):
        raise ValueError(
            f"state has {x.shape[0]} particles in {x.shape[1]}D: the scene {scene.name!r} has "
            f"{n} particles in {scene.dim}D"
        )
    check_shapes(
        scene,
        {k: np.asarray(getattr(state, k)) for k in ("x", "v", "stress", "damage") if getattr(state, k) is not None},
        "state",
    )
    if np.shape(state.t) != ():
        raise ValueError(f"state.t has shape {np.shape(state.t)}: allowed a scalar (s)")
    v, stress, d = np.asarray(state.v), np.asarray(state.stress), scene.dim
    lo, hi = np.asarray(scene.grid.origin), np.asarray(scene.grid.hi)
    colors = [f"C{i % 10}" for i in range(len(scene.phases))]
    title = f"{scene.name}: t = {float(np.asarray(state.t)):.4g} s"
    if d == 1:
        fig = Figure(figsize=(7, 5.5), layout="constrained")
        ax_v, ax_s = fig.subplots(2, 1, sharex=True)
        for phase, sl, c in zip(scene.phases, phase_slices(scene), colors):
            ax_v.plot(x[sl, 0], v[sl, 0], ".", ms=3, color=c, label=phase.name)
            ax_s.plot(x[sl, 0], stress[sl, 0, 0], ".", ms=3, color=c)
        ax_v.set_ylabel("velocity v_x (m/s)")
        ax_s.set_ylabel("stress sigma_xx (Pa)")
        ax_s.set_xlabel("x (m)")
        ax_s.set_xlim(lo[0], hi[0])
        ax_v.legend(loc="best", fontsize="small")
        ax_v.set_title(title)
    else:
        width = 6.5
        span = hi[:2] - lo[:2]
        damage = None if state.damage is None else np.asarray(state.damage)
        cracked = damage is not None and bool(np.any(damage > 0))  # a second panel: damage (the crack pattern)
        ratio = span[1] / span[0]
        panel_h = max(2.5, min(9.0, width * ratio))
        panel_w = min(width, max(2.0, panel_h / ratio + 1.2))  # as wide as the grid's aspect asks, with labels
        fig = Figure(
            figsize=(panel_w * (2 if cracked else 1) + (1.0 if cracked else 0.0), panel_h + 0.6), layout="constrained"
        )
        axes = fig.subplots(1, 2 if cracked else 1, squeeze=False)[0]
        spacing = min(scene.grid.h / p.ppc for p in scene.phases)
        size = max(0.3, (0.75 * width * 72 * spacing / span[0]) ** 2)
        ax = axes[0]
        for phase, sl, c in zip(scene.phases, phase_slices(scene), colors):
            ax.scatter(
                x[sl, 0], x[sl, 1], s=size, color=c, label=phase.name, linewidths=0, alpha=1.0 if d == 2 else 0.4
            )
        fig.legend(
            *ax.get_legend_handles_labels(),
            loc="outside lower center",
            ncols=min(4, len(scene.phases)),
            fontsize="small",
            markerscale=max(1.0, 20 / size),
            frameon=False,
        )  # outside the data
        ax.set_title(title + ("" if d == 2 else " (projection on x-y)"))
        if cracked:
            sc = axes[1].scatter(x[:, 0], x[:, 1], s=size, c=damage, cmap="coolwarm", vmin=0.0, vmax=1.0, linewidths=0)
            fig.colorbar(sc, ax=axes[1], label="damage (1: failed)")
            axes[1].set_title(f"damage: {float(np.mean(damage >= 1.0)):.1%} of the particles failed")
        for ax in axes:
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.set_xlabel("r (m)" if scene.axisymmetric else "x (m)")
            ax.set_ylabel("z (m)" if scene.axisymmetric else "y (m)")
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    return path


PLOT_FIELDS = ("speed", "pressure", "damage", "phase")


def _field_values(scene, state, field: str) -> np.ndarray:
    """(N,) values of `field` on the particles of one State: speed |v| (m/s), pressure (Pa: the
    state's, else -tr(stress)/3 or /d), damage (0..1), phase (its index in the scene)."""
    if field == "speed":
        v = np.asarray(state.v)
        return v[:, 0] if v.shape[-1] == 1 else np.linalg.norm(v, axis=-1)  # 1D: the signed velocity
    if field == "pressure":
        if state.pressure is not None:
            return np.asarray(state.pressure)
        s = np.asarray(state.stress)
        return -np.trace(s, axis1=-2, axis2=-1) / s.shape[-1]
    if field == "damage":
        return np.zeros(np.shape(state.x)[0]) if state.damage is None else np.asarray(state.damage)
    return np.concatenate([np.full(sl.stop - sl.start, i, float) for i, sl in enumerate(phase_slices(scene))])


FIELD_LABELS = {
    "speed": "speed |v| (m/s)",
    "pressure": "pressure (Pa)",
    "damage": "damage (1: failed)",
    "phase": "phase",
}


def _limits(values, field):
    """Colour limits shared by the snapshots: speed [0, max], pressure symmetric about 0 at the 99th
    percentile of |p| (a shock's peak does not wash out the rest), damage [0, 1]."""
    v = np.concatenate([np.ravel(a) for a in values])
    v = v[np.isfinite(v)]
    if field == "damage" or v.size == 0:
        return 0.0, 1.0
    if field == "pressure":
        a = float(np.percentile(np.abs(v), 99)) or 1.0
        return -a, a
    top = float(v.max())
    return 0.0, top if top > 0 else 1.0


def _times_of(n: int, panels: int) -> list[int]:
    """`panels` output indices spread evenly from the first to the last (fewer where n is smaller)."""
    return sorted({int(round(i)) for i in np.linspace(0, n - 1, min(panels, n))})


def run_figure(
    scene: Scene, history: State, field: str = "speed", panels: int = 4, params: Params | None = None
) -> Figure:
    """A matplotlib Figure of a run: `field` (PLOT_FIELDS) on the particles at `panels` output
    times in a row with one colorbar (1D: the field against x, one curve per time), and below them
    kinetic, internal and total energy against time over every output. Each snapshot panel is as
    wide as the grid's aspect asks (a tall axisymmetric grid gets narrow panels side by side, not
    a wide figure of empty space); legends sit outside the data."""
    # longer than 60 lines on purpose: one figure drawn top to bottom (matplotlib calls on shared axes)
    from matplotlib.figure import Figure  # matplotlib loaded only when a figure is drawn (its import is slow)
    from matplotlib.ticker import MaxNLocator  # as Figure: loaded when drawn

    if field not in PLOT_FIELDS:
        raise ValueError(f"field = {field!r} is invalid: allowed {' | '.join(PLOT_FIELDS)}")
    if isinstance(panels, bool) or not isinstance(panels, int) or panels < 1:
        raise ValueError(f"panels = {panels!r} is invalid: allowed an integer >= 1")
    x_all = np.asarray(history.x)
    if x_all.ndim != 3:
        raise ValueError(f"history.x has shape {x_all.shape}: allowed a run's history (outputs, particles, dim)")
    n_out = x_all.shape[0]
    params = default_params(scene, dtype=x_all.dtype) if params is None else params
    states = [jax_tree_index(history, i) for i in range(n_out)]
    energy = [diagnostics.summary(scene, params, s) for s in states]
    picks = _times_of(n_out, panels)
    values = [_field_values(scene, states[i], field) for i in picks]
    lo_c, hi_c = _limits(values, field)
    d = scene.dim
    lo, hi = np.asarray(scene.grid.origin), np.asarray(scene.grid.hi)
    if d == 1:
        fig = Figure(figsize=(8.5, 6.5), layout="constrained")
        ax_f, ax_e = fig.subplots(2, 1, height_ratios=(3, 2))
        for i, v in zip(picks, values):
            ax_f.plot(x_all[i, :, 0], v, ".", ms=3, label=f"t = {float(states[i].t):.3g} s")
        ax_f.set_xlim(lo[0], hi[0])
        ax_f.set_xlabel("x (m)")
        ax_f.set_ylabel("velocity v_x (m/s)" if field == "speed" else FIELD_LABELS[field])
        ax_f.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)
        ax_f.set_title(f"{scene.name}: {field}")
    else:
        span = hi[:2] - lo[:2]
        aspect = float(span[0] / span[1])
        panel_h = 3.2 if 3.2 * aspect >= 1.6 else min(7.0, 1.6 / aspect)  # a tall grid: taller panels
        panel_w = min(6.0, panel_h * aspect)
        panel_h = panel_w / aspect  # a wide grid: shorter panels
        fig = Figure(figsize=(max(6.0, len(picks) * (panel_w + 0.45) + 1.5), panel_h + 3.4), layout="constrained")
        top, bottom = fig.subfigures(2, 1, height_ratios=(panel_h + 0.6, 2.8))
        axes = top.subplots(1, len(picks), sharex=True, sharey=True, squeeze=False)[0]
        spacing = min(scene.grid.h / p.ppc for p in scene.phases)
        size = max(0.2, (0.8 * panel_w * 72 * spacing / span[0]) ** 2)
        cmap = {"speed": "viridis", "pressure": "coolwarm", "damage": "magma", "phase": "tab10"}[field]
        for ax, i, v in zip(axes, picks, values):
            x = x_all[i]
            sc = ax.scatter(
                x[:, 0],
                x[:, 1],
                s=size,
                c=v,
                cmap=cmap,
                vmin=lo_c if field != "phase" else -0.5,
                vmax=hi_c if field != "phase" else 9.5,
                linewidths=0,
                alpha=1.0 if d == 2 else 0.4,
            )
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.set_title(f"t = {float(states[i].t):.3g} s", fontsize="medium")
            ax.set_xlabel("r (m)" if scene.axisymmetric else "x (m)")
            ax.xaxis.set_major_locator(MaxNLocator(max(2, int(panel_w * 1.2))))  # labels that do not overlap
        axes[0].set_ylabel("z (m)" if scene.axisymmetric else "y (m)")
        if field == "phase":
            from matplotlib.lines import Line2D  # as Figure: loaded when drawn

            handles = [
                Line2D([], [], ls="", marker="o", color=f"C{k % 10}", label=p.name) for k, p in enumerate(scene.phases)
            ]
            top.legend(handles=handles, loc="outside right upper", fontsize="small", frameon=False)
        else:
            top.colorbar(sc, ax=list(axes), label=FIELD_LABELS[field], shrink=0.9)
        top.suptitle(f"{scene.name}: {field}" + ("" if d == 2 else " (projection on x-y)"))
        ax_e = bottom.subplots()
    t = [e["t"] for e in energy]
    unit = io_units("kinetic", scene)
    for key, name in (
        ("kinetic", "kinetic"),
        ("internal", "internal"),
        ("total_energy", "total, with gravity" if scene.gravity is not None else "total"),
    ):
        ax_e.plot(t, [e[key] for e in energy], ".-", ms=3, label=name)
    ax_e.set_xlabel("t (s)")
    ax_e.set_ylabel(f"energy ({unit})")
    ax_e.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)
    ax_e.grid(alpha=0.3)
    return fig


def jax_tree_index(tree: Any, i: int) -> Any:
    """The i-th State of a history (the leading axis indexed; None leaves kept)."""
    return jax.tree.map(lambda a: None if a is None else np.asarray(a)[i], tree)


def io_units(name: str, scene: Scene) -> str:
    """The SI unit text of the output field `name` in `scene`'s dimension and geometry."""
    return units(name, scene.dim, scene.axisymmetric)


def plot_run(
    scene: Scene,
    history: State,
    path: str | os.PathLike,
    field: str = "speed",
    panels: int = 4,
    params: Params | None = None,
    overwrite: bool = False,
) -> Path:
    """PNG of `run_figure` (a field at several times with a colorbar, and energy against time).
    Returns the path; FileExistsError if it exists and not `overwrite`; ValueError for a path
    that does not end in .png, an unknown field, or a history that does not fit the scene."""
    path = Path(path)
    if path.suffix != ".png":
        raise ValueError(f"path = {os.fspath(path)!r} is invalid: allowed a file name ending in .png")
    check_new(path, overwrite=overwrite)
    check_scene(scene)
    if not isinstance(history, State):
        raise ValueError(
            f"history = {type(history).__name__} is invalid: allowed a jaxmpm.State with a leading "
            "output axis (simulate's history)"
        )
    x = np.asarray(history.x)
    n = phase_slices(scene)[-1].stop
    if x.ndim != 3 or x.shape[1:] != (n, scene.dim):
        raise ValueError(f"history.x has shape {x.shape}: the scene {scene.name!r} needs (outputs, {n}, {scene.dim})")
    fig = run_figure(scene, history, field, panels, params)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    return path
