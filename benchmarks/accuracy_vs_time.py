"""What accuracy costs in time: error against wall time on two problems with exact solutions.

Problems:
  bar   the vibrating bar of PHYSICS section 4 (Bardenhagen 2002; built-in `vibrating_bar`) at
        v0 = 0.1 m/s, where particles cross cells, over one period (10 s): RMS displacement error
        against the exact u(X, t), relative to the amplitude v0 / omega.
  sod   Sod's shock tube (rho, p = 1, 1 | 0.125, 0.1, gamma = 1.4, artificial viscosity 0.5, 2.0) at
        t = 0.2: volume-weighted L1 density error relative to the exact Riemann solution.
  dam   the water dam break of tests/test_fluids.py (column a x 2a, a = 0.057 m, in a 5a x 5a box,
        Tait water at c = 25 m/s, CFL 0.3) to T = t sqrt(2 g / a) = 3.6, just before the surge
        reaches the far wall: the front Z = x / a against T beside Martin & Moyce's (1952)
        measurements; error |front speed / measured - 1| as in the test (Z from 3.5 to 4.75 against
        the experiment's once past the gate's opening). Rows: 'ddmp' (the default, with the fluids'
        artificial viscosity and density diffusion), 'ddmp-no-diffusion' (the default before the
        diffusion: density_diffusion 0), 'ddmp-no-av' (artificial_viscosity (0, 0)) and
        'bspline2-apic', at --dam-cells cells per a (20, 40 by default; 80 where affordable).
  debris the debris cloud (built-in `debris_cloud`, one field, 6 us, float64) at the seed's best C_h
        (0.02, --debris-ch) in the default configuration ('failed') and in 'tensile', at
        --debris-resolutions (0.75, 1, 1.5, 2 by default; 3 takes 10-15 minutes a row): the feature
        velocities (points 1, 2, 4, km/s, as `python -m calibration table`) and the error, the largest
        |v - measured| of the three against Piekutowski's experiment (km/s, absolute). The seed's own
        error at that C_h is drawn for reference (0.13 km/s at C_h = 0.02). Its 'cells' column holds
        100 x the resolution.
Settings: shape function (linear MPM, DDMP, quadratic B-spline with the musl update and with APIC),
cells, particles per cell per axis (2 or 4 on the bar; Sod has 8 per cell on the left and 1 on the
right, equal particle masses), float32 / float64; CFL 0.1 (bar) and 0.3 (sod).
The quadratic B-spline needs half a cell between the particles and the grid's edge: its bar has one
more cell before x = 0 and holds the two first node layers fixed (the end at x = 0 is then fixed as
for the hat functions); Sod is run with hat functions only (its gas fills the tube wall to wall).

Wall time: each configuration is compiled and run once, then the median of --repeats further runs
from the same initial state (`jaxmpm.simulate`'s host driver, no progress bar) is taken. All rows
run in this one process, one after another; the numbers to compare are ratios within one run.

Output: a CSV (--out, default benchmarks/results/accuracy_vs_time.csv) with problem, shape, cells,
ppc, dtype, steps, particles, wall_s, error; a PNG next to it with error against wall time per
problem and the Pareto front; printed: the front, and DDMP's error against linear MPM's at equal wall
time (linear MPM's smallest error among its runs that took no longer than DDMP's run).

Run:  python benchmarks/accuracy_vs_time.py                # bar, sod and dam (the debris cloud only with --only debris)
      python benchmarks/accuracy_vs_time.py --only debris --repeats 0 --out X.csv   # the debris cloud alone, one timed run a row
      python benchmarks/accuracy_vs_time.py --only dam --dam-cells 10,20 --repeats 1 --out X.csv   # the dam break alone
      python benchmarks/accuracy_vs_time.py --only dam --dam-cells 80 --dam-schemes ddmp --repeats 0 --out X.csv
      python benchmarks/accuracy_vs_time.py --quick        # fewer rows, 2 minutes
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxmpm  # noqa: E402
from jaxmpm.model.scene import DENSITY_DIFFUSION, Boundary, Box, Grid, Phase, Scene  # noqa: E402
from jaxmpm.scenes import initial_state  # noqa: E402
from jaxmpm.scenes.basic import BAR_LENGTH, vibrating_bar  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from outputs import add_overwrite, check_outputs, check_table  # noqa: E402  benchmarks/outputs.py
from riemann import sample  # noqa: E402  (exact Riemann solution, shared with the tests)
from test_fluids import MARTIN_MOYCE, dam_break, front_speed  # noqa: E402  (the dam break, shared with the tests)

C_BAR = 10.0
BETA = math.pi / (2 * BAR_LENGTH)
OMEGA = BETA * C_BAR
PERIOD = 2 * math.pi / OMEGA
V0 = 0.1

SHAPES = {
    "linear": ("linear", "musl"),
    "ddmp": ("ddmp", "musl"),
    "bspline2": ("bspline2", "musl"),
    "bspline2-apic": ("bspline2", "apic"),
}


def _cast(tree, dtype):
    return jax.tree.map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, tree)


def bar_scene(shape, cells, ppc):
    kind, transfer = SHAPES[shape]
    scene = vibrating_bar(cells=cells, v0=V0, shape=kind, cfl=0.1, ppc=ppc)
    return dataclasses.replace(scene, transfer=transfer)


def bar_error(scene, s0, final):
    X = np.asarray(s0.x[:, 0], float)
    u = np.asarray(final.x[:, 0], float) - X
    exact = V0 / OMEGA * math.sin(OMEGA * float(final.t)) * np.sin(BETA * X)
    return float(np.sqrt(np.mean((u - exact) ** 2)) / (V0 / OMEGA))


def sod_scene(shape, cells, ppc):
    left = jaxmpm.Material.make("left", "ideal_gas", rho0=1.0, gamma=1.4, p0=1.0)
    right = jaxmpm.Material.make("right", "ideal_gas", rho0=0.125, gamma=1.4, p0=0.1)
    kind, transfer = SHAPES[shape]
    return Scene(
        grid=Grid(cells=(cells,), h=1.0 / cells),
        materials=(left, right),
        shape=kind,
        transfer=transfer,
        phases=(
            Phase("left", "left", Box((0.0,), (0.5,)), ppc=8),  # equal particle masses
            Phase("right", "right", Box((0.5,), (1.0,)), ppc=1),
        ),
        artificial_viscosity=(0.5, 2.0),
        cfl=0.3,
        t_end=0.2,
        n_out=1,
        boundary=Boundary(faces=(("x_lo", "slip"), ("x_hi", "slip"))),
    )


def sod_error(scene, s0, final):
    x = np.asarray(final.x[:, 0], float)
    V = np.asarray(final.volume, float)
    rho = np.asarray(final.mass / final.volume, float)
    exact = sample(x, float(final.t), 0.5, (1.0, 0.0, 1.0), (0.125, 0.0, 0.1), 1.4)[0]
    return float(np.sum(V * np.abs(rho - exact)) / np.sum(V * exact))


DAM_T_END = 3.6
DAM_SCHEMES = {  # shape, transfer, artificial viscosity (None: the default), density diffusion delta
    "ddmp": ("ddmp", "musl", None, DENSITY_DIFFUSION),
    "ddmp-no-diffusion": ("ddmp", "musl", None, 0.0),
    "ddmp-no-av": ("ddmp", "musl", (0.0, 0.0), DENSITY_DIFFUSION),
    "bspline2-apic": ("bspline2", "apic", None, DENSITY_DIFFUSION),
}


def dam_scene(shape, cells, ppc):
    kind, transfer, av, delta = DAM_SCHEMES[shape]
    changes = dict(shape=kind, transfer=transfer, artificial_viscosity=av, density_diffusion=delta)
    if kind == "bspline2":  # half a cell between the particles and the walls: the box one cell larger each way
        base = dam_break(cells, DAM_T_END)
        h = base.grid.h
        changes.update(
            grid=Grid(cells=tuple(n + 2 for n in base.grid.cells), h=h, origin=(-h, -h)),
            boundary=dataclasses.replace(base.boundary, layers=2),
        )
    return dam_break(cells, DAM_T_END, **changes)


def dam_error(scene, s0, final, hist=None):
    T = np.asarray(hist.t) * math.sqrt(2 * 9.81 / 0.057)
    Z = np.asarray(jnp.max(hist.x[..., 0], axis=-1)) / 0.057
    late = (MARTIN_MOYCE[:, 0] >= 3.0) & (MARTIN_MOYCE[:, 0] <= 5.1)
    measured = np.polyfit(MARTIN_MOYCE[late, 0], MARTIN_MOYCE[late, 1], 1)[0]
    return abs(front_speed(T, Z, 3.5, 4.75) / measured - 1), (T.tolist(), Z.tolist())


DEBRIS_CH = 0.02  # the seed's best C_h against the experiment
DEBRIS_CONFIGS = ("failed", "tensile")
SEED_ERROR = 0.13  # the seed's largest |v - measured| at C_h = 0.02 (6.29 / 5.97 / 3.92 against 6.3 / 6.1 / 3.9)


def debris_scene(shape, cells, ppc, c_h=DEBRIS_CH):
    """`shape` is the closure's configuration, `cells` the resolution in hundredths (75: 0.75)."""
    return jaxmpm.load_scene("debris_cloud", resolution=cells / 100, fields=1, c_h=c_h, fragmentation=shape)


def debris_error(scene, s0, final, hist=None):
    """Largest |v - measured| (km/s) over points 1, 2, 4, and the three velocities (km/s), from the
    later half of the run as `python -m calibration table` measures them."""
    from calibration.data import load
    from jaxmpm.features import feature_velocities

    v = -np.asarray(feature_velocities(scene, hist, first=hist.t.shape[0] // 2)) / 1000.0
    return float(np.max(np.abs(v - load().experiment))), v


PROBLEMS = {
    "bar": (bar_scene, bar_error, PERIOD),
    "sod": (sod_scene, sod_error, 0.2),
    "dam": (dam_scene, dam_error, None),
    "debris": (debris_scene, debris_error, None),
}


def measure(problem, shape, cells, ppc, dtype, repeats):
    build, error, t_end = PROBLEMS[problem]
    scene = build(shape, cells, ppc)
    t_end = scene.t_end if t_end is None else t_end
    n_out = {"dam": 36, "debris": 12}.get(problem, 1)
    params = jaxmpm.default_params(scene)
    s0 = initial_state(scene, params)
    if dtype == "float32":
        params, s0 = _cast(params, jnp.float32), _cast(s0, jnp.float32)
    t0 = time.perf_counter()
    final, hist = jaxmpm.simulate(scene, params, s0, t_end=t_end, n_out=n_out, progress=False)  # compiles
    jax.block_until_ready(final)
    times = [time.perf_counter() - t0] if repeats == 0 else []  # --repeats 0: the first run, compilation included
    for _ in range(repeats):
        t0 = time.perf_counter()
        final, hist = jaxmpm.simulate(scene, params, s0, t_end=t_end, n_out=n_out, progress=False)
        jax.block_until_ready(final)
        times.append(time.perf_counter() - t0)
    finite = all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(final))
    extra = {}
    if problem == "dam":
        err, (T, Z) = error(scene, s0, final, hist) if finite else (float("nan"), ([], []))
        extra = {"front_T": " ".join(f"{t:.3f}" for t in T), "front_Z": " ".join(f"{z:.4f}" for z in Z)}
    elif problem == "debris":
        err, v = error(scene, s0, final, hist) if finite else (float("nan"), [float("nan")] * 3)
        extra = {"v1_km_s": round(float(v[0]), 3), "v2_km_s": round(float(v[1]), 3), "v4_km_s": round(float(v[2]), 3)}
    else:
        err = error(scene, s0, final) if finite else float("nan")
    from jaxmpm.step import cfl_time_step

    dt = float(cfl_time_step(scene, params, s0))  # the first step (at the scene's CFL)
    return {
        "problem": problem,
        "shape": shape,
        "cells": cells,
        "ppc": ppc,
        "dtype": dtype,
        "steps": int(math.ceil(t_end / dt)),
        "particles": int(s0.x.shape[0]),
        "wall_s": statistics.median(times),
        "error": err,
        **extra,
    }


def rows_to_run(quick, dam_cells=(20, 40), only=None, debris_resolutions=(0.75, 1.0, 1.5, 2.0), dam_schemes=None):
    if only == "debris":
        return [("debris", c, round(100 * r), 2, "float64") for c in DEBRIS_CONFIGS for r in debris_resolutions]
    out = []
    for shape in dam_schemes or DAM_SCHEMES:
        for cells in dam_cells:
            out.append(("dam", shape, cells, 2, "float64"))
    if only == "dam":
        return out
    return _bar_and_sod_rows(quick) + out


def _bar_and_sod_rows(quick):
    cells_bar = [25, 50, 100, 200] if quick else [25, 50, 100, 200, 400]
    cells_sod = [100, 200, 400] if quick else [100, 200, 400, 800, 1600]
    out = []
    for shape in ("linear", "ddmp", "bspline2", "bspline2-apic"):
        for cells in cells_bar:
            out.append(("bar", shape, cells, 2, "float64"))
    for shape in ("linear", "ddmp"):
        for cells in cells_bar[1:3]:
            out.append(("bar", shape, cells, 4, "float64"))
            out.append(("bar", shape, cells, 2, "float32"))
    for shape in ("linear", "ddmp"):
        for cells in cells_sod:
            out.append(("sod", shape, cells, 2, "float64"))
        out.append(("sod", shape, cells_sod[1], 2, "float32"))
    return out


def pareto(rows):
    """Rows not beaten in both wall time and error by another row."""
    ok = [r for r in rows if math.isfinite(r["error"])]
    return sorted(
        [r for r in ok if not any(o["wall_s"] <= r["wall_s"] and o["error"] < r["error"] for o in ok if o is not r)],
        key=lambda r: r["wall_s"],
    )


def best_error_within(rows, t):
    """The smallest error among `rows` that ran in at most wall time t (None if none did): what
    that method buys with t seconds."""
    errs = [r["error"] for r in rows if r["wall_s"] <= t and math.isfinite(r["error"])]
    return min(errs) if errs else None


def _shape_names():
    """Every row's scheme name, in the order that gives each its colour."""
    return list(SHAPES) + [s for s in DAM_SCHEMES if s not in SHAPES] + list(DEBRIS_CONFIGS)


def read_rows(path):
    """The rows of a table this script wrote (numbers back to numbers)."""
    with open(path) as f:
        lines = [line for line in f if not line.startswith("#")]
    rows = list(csv.DictReader(lines))
    for r in rows:
        for k in ("cells", "ppc", "steps", "particles"):
            r[k] = int(r[k])
        for k in ("wall_s", "error"):
            r[k] = float(r[k])
    return rows


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problems = sorted({r["problem"] for r in rows})
    n_ax = len(problems) + ("dam" in problems)
    fig, axes = plt.subplots(1, n_ax, figsize=(6.5 * n_ax, 5), squeeze=False)
    markers = {"float64": "o", "float32": "s"}
    if "dam" in problems:
        plot_dam_fronts(axes[0][-1], [r for r in rows if r["problem"] == "dam"])
    for ax, prob in zip(axes[0], problems):
        sub = [r for r in rows if r["problem"] == prob and math.isfinite(r["error"])]
        for k, shape in enumerate(_shape_names()):
            for ppc in (2, 4):
                for dt, mk in markers.items():
                    pts = sorted(
                        [r for r in sub if r["shape"] == shape and r["ppc"] == ppc and r["dtype"] == dt],
                        key=lambda r: r["cells"],
                    )
                    if pts:
                        ax.plot(
                            [r["wall_s"] for r in pts],
                            [r["error"] for r in pts],
                            marker=mk,
                            ls="-" if ppc == 2 and dt == "float64" else "none",
                            color=f"C{k}",
                            mfc="none" if ppc == 4 else None,
                            label=f"{shape}, ppc {ppc}, {dt}",
                        )
        front = pareto(sub)
        ax.plot([r["wall_s"] for r in front], [r["error"] for r in front], "k:", lw=1, label="Pareto front")
        if prob == "debris":
            ax.axhline(SEED_ERROR, color="0.4", ls="--", lw=1, label=f"the seed's error at C_h = {DEBRIS_CH}")
            for r in sub:
                ax.annotate(f"res {r['cells'] / 100:g}", (r["wall_s"], r["error"]), fontsize="x-small")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("largest |v - measured| (km/s)" if prob == "debris" else "relative error")
        ax.set_title(
            {
                "bar": "vibrating bar, v0 = 0.1 m/s, one period",
                "sod": "Sod shock tube, t = 0.2",
                "dam": "dam break: |front speed / Martin & Moyce - 1|",
                "debris": f"debris cloud, C_h = {DEBRIS_CH}: points 1, 2, 4 against Piekutowski",
            }[prob]
        )
        ax.legend(fontsize="x-small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_dam_fronts(ax, rows):
    """The dam break's surge front Z = x / a against T per scheme and resolution, and Martin & Moyce's."""
    for r in rows:
        if not r.get("front_T"):
            continue
        k = _shape_names().index(r["shape"])
        T = [float(t) for t in r["front_T"].split()]
        Z = [float(z) for z in r["front_Z"].split()]
        ax.plot(
            T,
            Z,
            color=f"C{k}",
            lw=0.8 + 0.5 * math.log2(r["cells"] / 10),
            ls="--" if "no-av" in r["shape"] else ":" if "no-diffusion" in r["shape"] else "-",
            label=f"{r['shape']}, {r['cells']} cells per a, {r['wall_s']:.0f} s",
        )
    ax.plot(MARTIN_MOYCE[:, 0], MARTIN_MOYCE[:, 1], "ks", label="Martin & Moyce (1952), a = 2.25 in")
    ax.axhline(5.0, color="0.5", lw=0.5)
    ax.set_xlim(0, DAM_T_END)
    ax.set_ylim(1, 5.2)
    ax.set_xlabel("T = t sqrt(2 g / a)")
    ax.set_ylabel("front Z = x / a")
    ax.set_title("dam break: surge front (far wall at Z = 5)")
    ax.legend(fontsize="x-small")


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs after the compiling one (0: time that one)")
    ap.add_argument("--only", choices=("dam", "debris"), help="only the dam break's or the debris cloud's rows")
    ap.add_argument(
        "--debris-resolutions",
        default="0.75,1,1.5,2",
        help="the debris cloud's resolutions, comma-separated (debris_cloud's; 3 takes 10-15 minutes a row)",
    )
    ap.add_argument(
        "--dam-cells",
        help="the dam break's cells per column width a, comma-separated (default 20,40; 10,20 with --quick)",
    )
    ap.add_argument(
        "--dam-schemes",
        help=f"the dam break's rows, comma-separated, of {', '.join(DAM_SCHEMES)} (default: all)",
    )
    ap.add_argument("--out", default=str(HERE / "results" / "accuracy_vs_time.csv"))
    add_overwrite(ap)
    ap.add_argument("--replot", metavar="CSV", help="only draw the PNG of a table this script wrote")
    args = ap.parse_args(argv)
    if args.replot:
        table = check_table(args.replot)
        check_outputs(table.with_suffix(".png"), overwrite=args.overwrite)
        plot(read_rows(table), table.with_suffix(".png"))
        return
    out = Path(args.out)
    check_outputs(out, out.with_suffix(".png"), overwrite=args.overwrite)
    rows = []
    dam_cells = args.dam_cells or ("10,20" if args.quick else "20,40")
    debris_resolutions = tuple(float(r) for r in args.debris_resolutions.split(","))
    dam_schemes = args.dam_schemes.split(",") if args.dam_schemes else None
    unknown = sorted(set(dam_schemes or ()) - set(DAM_SCHEMES))
    if unknown:
        ap.error(f"--dam-schemes: unknown {', '.join(unknown)}; allowed: {', '.join(DAM_SCHEMES)}")
    cells = tuple(int(c) for c in dam_cells.split(","))
    for spec in rows_to_run(args.quick, cells, args.only, debris_resolutions, dam_schemes):
        r = measure(*spec, repeats=args.repeats)
        rows.append(r)
        print(
            f"{r['problem']:4s} {r['shape']:14s} cells {r['cells']:5d} ppc {r['ppc']} {r['dtype']}: "
            f"{r['particles']:5d} particles, {r['steps']:6d} steps, {r['wall_s']:8.3f} s, error {r['error']:.3e}",
            flush=True,
        )
        with open(out, "w", newline="") as f:
            f.write(
                f"# jaxmpm accuracy_vs_time, {datetime.date.today()}, jax {jax.__version__}, "
                f"{jax.devices()[0].platform}, {platform.processor() or platform.machine()}\n"
            )
            w = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
            w.writeheader()
            w.writerows(rows)
    png = out.with_suffix(".png")
    plot(rows, png)
    for prob in ("bar", "sod", "dam", "debris"):
        if not any(r["problem"] == prob for r in rows):
            continue
        print(f"\nPareto front, {prob}:")
        for r in pareto([r for r in rows if r["problem"] == prob]):
            print(
                f"  {r['shape']:14s} cells {r['cells']:5d} ppc {r['ppc']} {r['dtype']}: {r['wall_s']:.3f} s, "
                f"error {r['error']:.3e}"
            )
    for prob in ("bar", "sod"):
        if not any(r["problem"] == prob for r in rows):
            continue
        lin = [r for r in rows if r["problem"] == prob and r["shape"] == "linear"]
        print(f"\n{prob}, DDMP against linear MPM at equal wall time (linear's best error within DDMP's time):")
        for r in sorted([r for r in rows if r["problem"] == prob and r["shape"] == "ddmp"], key=lambda r: r["wall_s"]):
            e_lin = best_error_within(lin, r["wall_s"])
            ratio = (
                "no linear run that fast" if e_lin is None else f"linear {e_lin:.3e}, ratio {e_lin / r['error']:.1f}x"
            )
            print(
                f"  ddmp cells {r['cells']:4d} ppc {r['ppc']} {r['dtype']}: {r['wall_s']:.3f} s, error "
                f"{r['error']:.3e}; {ratio}"
            )
    print(f"\nwrote {out} and {png}")


if __name__ == "__main__":
    main()
