"""Figures of the C_h table and of a fit (matplotlib, written atomically, never over a file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxmpm.io.files import atomic_write, check_new


def _save(fig, path):
    path = Path(path)
    check_new(path)
    with atomic_write(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    return path


def ch_table(rows, path):
    """Feature velocity against C_h: jaxmpm and the seed as lines, the experiment as bands."""
    from matplotlib.figure import Figure  # matplotlib loaded only when a figure is drawn (its import is slow)

    fig = Figure(figsize=(9, 3.4), layout="constrained")
    axes = fig.subplots(1, 3, sharey=True)
    exp = next(r for r in rows if r["source"] == "experiment")["v"]
    for i, (ax, point) in enumerate(zip(axes, (1, 2, 4))):
        for src, style in (("seed", "s--"), ("jaxmpm", "o-")):
            rs = [r for r in rows if r["source"] == src]
            ax.plot([r["C_h"] for r in rs], [r["v"][i] for r in rs], style, label=src)
        ax.axhline(exp[i], color="k", lw=1, label="experiment")
        ax.set_xscale("log")
        ax.set_xlabel("C_h")
        ax.set_title(f"point {point}")
    axes[0].set_ylabel("axial velocity (km/s)")
    axes[0].legend(fontsize="small")
    return _save(fig, path)


def fit_report(result, out):
    """loss history, residuals beside the seed's best, and the landscape (when computed)."""
    from matplotlib.figure import Figure  # matplotlib loaded only when a figure is drawn (its import is slow)

    out = Path(out)
    paths = []
    h = result["history"]
    fig = Figure(figsize=(8, 3.2), layout="constrained")
    a, b = fig.subplots(1, 2)
    a.semilogy([x["iteration"] for x in h], [x["loss"] for x in h], "o-")
    a.set_xlabel("iteration")
    a.set_ylabel("loss ((km/s)^2)")
    b.plot([x["C_d"] for x in h], [x["C_h"] for x in h], "o-", ms=3)
    b.set_xscale("log")
    b.set_yscale("log")
    b.set_xlabel("C_d")
    b.set_ylabel("C_h")
    for st in result.get("starts") or []:  # the multi-start fit: every start and where it ended
        b.annotate(
            "",
            (st["C_d"], st["C_h"]),
            (st["start_C_d"], st["start_C_h"]),
            arrowprops=dict(arrowstyle="->", color="C3" if st["best"] else "0.5", lw=0.8),
        )
    b.set_title("path" + (" (arrows: every start, red: the best)" if result.get("starts") else ""))
    paths.append(_save(fig, out / "loss_history.png"))
    fig = Figure(figsize=(5, 3.2), layout="constrained")
    ax = fig.subplots()
    pts = np.arange(3)
    ax.bar(pts - 0.2, result["residuals_km_s"], width=0.4, label="fit")
    seed = np.array([6.29, 5.97, 3.92]) - np.array(result["experiment_km_s"])
    ax.bar(pts + 0.2, seed, width=0.4, label="seed, C_h = 0.02")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(pts, [f"point {p}" for p in result["points"]])
    ax.set_ylabel("model - experiment (km/s)")
    ax.legend(fontsize="small")
    paths.append(_save(fig, out / "residuals.png"))
    if result.get("landscape"):
        L = result["landscape"]
        fig = Figure(figsize=(5, 4), layout="constrained")
        ax = fig.subplots()
        cs = ax.contourf(L["C_d"], L["C_h"], np.log10(np.asarray(L["loss"])), levels=12)
        fig.colorbar(cs, label="log10 loss ((km/s)^2)")
        ax.plot([x["C_d"] for x in h], [x["C_h"] for x in h], "w.-", ms=3)
        ax.plot(result["fitted"]["C_d"], result["fitted"]["C_h"], "r*", ms=12)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("C_d")
        ax.set_ylabel("C_h")
        paths.append(_save(fig, out / "landscape.png"))
    return paths
