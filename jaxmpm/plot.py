"""PNG plots of a State (`plot_state`, also `jaxmpm.io.plot_state`)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxmpm.files import _atomic, check_new
from jaxmpm.io import _check_scene, _check_shapes
from jaxmpm.state import State, phase_slices


def plot_state(scene, state: State, path, overwrite: bool = False) -> Path:
    """PNG of one State (no time axis), particles coloured by phase: 2D a scatter of x, 1D velocity
    and stress against position, 3D the projection on the x-y plane; in 2D and 3D a second panel
    coloured by damage where any particle is damaged (the crack pattern). Returns the path.
    Raises FileExistsError if `path` exists and not `overwrite` (or is a directory); ValueError if
    `path` does not end in .png or the state does not fit the scene."""
    from matplotlib.figure import Figure

    path = Path(path)
    if path.suffix != ".png":
        raise ValueError(f"path = {os.fspath(path)!r} is invalid: allowed a file name ending in .png")
    check_new(path, overwrite=overwrite)              # and it is not a directory, even with overwrite
    _check_scene(scene)
    if not isinstance(state, State):
        raise ValueError(f"state = {type(state).__name__} is invalid: allowed a jaxmpm.State (one State, e.g. "
                         "jax.tree.map(lambda a: a[-1], history))")
    x = np.asarray(state.x)
    if x.ndim != 2:
        raise ValueError(f"state.x has shape {x.shape}: plot one State, e.g. jax.tree.map(lambda a: a[-1], history)")
    n = phase_slices(scene)[-1].stop
    if x.shape != (n, scene.dim):
        raise ValueError(f"state has {x.shape[0]} particles in {x.shape[1]}D: the scene {scene.name!r} has "
                         f"{n} particles in {scene.dim}D")
    _check_shapes(scene, {k: np.asarray(getattr(state, k)) for k in ("x", "v", "stress", "damage")
                          if getattr(state, k) is not None}, "state")
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
        cracked = damage is not None and bool(np.any(damage > 0))      # a second panel: damage (the crack pattern)
        fig = Figure(figsize=(width * (2 if cracked else 1), max(2.5, min(9.0, width * span[1] / span[0]))),
                     layout="constrained")
        axes = fig.subplots(1, 2 if cracked else 1, squeeze=False)[0]
        spacing = min(scene.grid.h / p.ppc for p in scene.phases)
        size = max(0.3, (0.75 * width * 72 * spacing / span[0]) ** 2)
        ax = axes[0]
        for phase, sl, c in zip(scene.phases, phase_slices(scene), colors):
            ax.scatter(x[sl, 0], x[sl, 1], s=size, color=c, label=phase.name, linewidths=0,
                       alpha=1.0 if d == 2 else 0.4)
        ax.legend(loc="upper right", fontsize="small", markerscale=max(1.0, 20 / size))
        ax.set_title(title + ("" if d == 2 else " (projection on x-y)"))
        if cracked:
            sc = axes[1].scatter(x[:, 0], x[:, 1], s=size, c=damage, cmap="coolwarm", vmin=0.0, vmax=1.0,
                                 linewidths=0)
            fig.colorbar(sc, ax=axes[1], label="damage (1: failed)")
            axes[1].set_title(f"damage: {float(np.mean(damage >= 1.0)):.1%} of the particles failed")
        for ax in axes:
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[1], hi[1])
            ax.set_aspect("equal")
            ax.set_xlabel("r (m)" if scene.axisymmetric else "x (m)")
            ax.set_ylabel("z (m)" if scene.axisymmetric else "y (m)")
    with _atomic(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    return path
