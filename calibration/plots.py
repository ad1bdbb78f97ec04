"""Figures of the C_h table and of a fit (matplotlib, written atomically, never over a file)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from jaxmpm.io.files import atomic_write, check_new

if TYPE_CHECKING:  # matplotlib loaded only when a figure is drawn (its import is slow)
    from matplotlib.figure import Figure


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    """Write fig as a PNG at path (a new file), atomically."""
    path = Path(path)
    check_new(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    return path


def ch_table(rows: list[dict[str, Any]], path: str | os.PathLike) -> Path:
    """Feature velocity against C_h: jaxmpm and the seed as lines, the experiment as bands. rows: dicts
    of source ('experiment', 'seed' or 'jaxmpm'), C_h and v (3,) km/s."""
    from matplotlib.figure import Figure  # matplotlib loaded only when a figure is drawn (its import is slow)

    fig = Figure(figsize=(9, 3.4), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    experiment = next(r for r in rows if r["source"] == "experiment")["v"]
    for i, (ax, point) in enumerate(zip(axes, (1, 2, 4))):
        for src, style in (("seed", "s--"), ("jaxmpm", "o-")):
            source_rows = [r for r in rows if r["source"] == src]
            ax.plot([r["C_h"] for r in source_rows], [r["v"][i] for r in source_rows], style, label=src)
        ax.axhline(experiment[i], color="k", lw=1, label="experiment")
        ax.set_xscale("log")
        ax.set_xlabel("C_h")
        ax.set_title(f"point {point}")
    axes[0].set_ylabel("axial velocity (km/s)")
    axes[0].legend(fontsize="small")
    return _save(fig, path)


def fit_report(result: dict[str, Any], out: str | os.PathLike) -> list[Path]:
    """loss history, residuals beside the seed's best, and the landscape (when computed), as PNGs in
    out; result: the content of the fit's result.json."""
    from matplotlib.figure import Figure  # matplotlib loaded only when a figure is drawn (its import is slow)

    out = Path(out)
    paths = []
    history = result["history"]
    fig = Figure(figsize=(8, 3.2), layout="constrained")
    loss_axes, path_axes = fig.subplots(1, 2)
    loss_axes.semilogy([x["iteration"] for x in history], [x["loss"] for x in history], "o-")
    loss_axes.set_xlabel("iteration")
    loss_axes.set_ylabel("loss ((km/s)^2)")
    path_axes.plot([x["C_d"] for x in history], [x["C_h"] for x in history], "o-", ms=3)
    path_axes.set_xscale("log")
    path_axes.set_yscale("log")
    path_axes.set_xlabel("C_d")
    path_axes.set_ylabel("C_h")
    for start in result.get("starts") or []:  # the multi-start fit: every start and where it ended
        path_axes.annotate(
            "",
            (start["C_d"], start["C_h"]),
            (start["start_C_d"], start["start_C_h"]),
            arrowprops=dict(arrowstyle="->", color="C3" if start["best"] else "0.5", lw=0.8),
        )
    path_axes.set_title("path" + (" (arrows: every start, red: the best)" if result.get("starts") else ""))
    paths.append(_save(fig, out / "loss_history.png"))
    fig = Figure(figsize=(5, 3.2), layout="constrained")
    ax = fig.subplots()
    points = np.arange(3)
    ax.bar(points - 0.2, result["residuals_km_s"], width=0.4, label="fit")
    seed = np.array([6.29, 5.97, 3.92]) - np.array(result["experiment_km_s"])
    ax.bar(points + 0.2, seed, width=0.4, label="seed, C_h = 0.02")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(points, [f"point {p}" for p in result["points"]])
    ax.set_ylabel("model - experiment (km/s)")
    ax.legend(fontsize="small")
    paths.append(_save(fig, out / "residuals.png"))
    if result.get("landscape"):
        land = result["landscape"]
        fig = Figure(figsize=(5, 4), layout="constrained")
        ax = fig.subplots()
        cs = ax.contourf(land["C_d"], land["C_h"], np.log10(np.asarray(land["loss"])), levels=12)
        fig.colorbar(cs, label="log10 loss ((km/s)^2)")
        ax.plot([x["C_d"] for x in history], [x["C_h"] for x in history], "w.-", ms=3)
        ax.plot(result["fitted"]["C_d"], result["fitted"]["C_h"], "r*", ms=12)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("C_d")
        ax.set_ylabel("C_h")
        paths.append(_save(fig, out / "landscape.png"))
    return paths
