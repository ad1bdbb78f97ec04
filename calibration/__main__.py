"""python -m calibration {table,fit,synthetic} ...: the debris cloud's feature velocities against C_h (table),
the fit of (C_d, C_h) to the experiment (fit), the recovery of known (C_d, C_h) (synthetic); see
calibration/__init__.py."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from calibration import plots
from calibration import fit as fitting
from calibration.arguments import (
    c_h_values,
    check_scene,
    iterations,
    measurements,
    model_header,
    new_folder,
    pair,
    positive,
    setup_model,
    versions,
)
from calibration.fit_command import cmd_fit
from calibration.data import Measurements
from calibration.model import theta_of, through_plate_warning
from calibration import synthetic
from jaxmpm.run import compile_cache
from jaxmpm.scenes.impact import DEBRIS_VISCOSITY
from jaxmpm.numerics.compile import jit

SEED_CH = (0.02, 0.15, 0.5, 1.0)


def cmd_table(args: argparse.Namespace) -> int:
    """`python -m calibration table`: the feature velocities for each --c-h, in one vmapped call,
    beside the experiment and the seed's (ch_table.csv, ch_table.png)."""
    values = c_h_values(args.c_h, "--c-h")
    positive(args.drag, "--drag", " (C_d)")
    check_scene(args, fields=(1, 2))
    meas = measurements(args.data)
    out = new_folder(args.out)
    model = setup_model(args)
    print(f"{model_header(args, model)}; C_h = {values} in one vmapped call", flush=True)
    t0 = time.perf_counter()
    thetas = np.log(np.stack([np.full(len(values), args.drag), values], -1))
    v, lead = (np.asarray(a) for a in model.table_batch(thetas, allow_short=True))
    wall = time.perf_counter() - t0
    for c, vi in zip(values, v):
        if np.isnan(vi).any():
            print(
                f"C_h = {c:g}: the run did not reach t_end in {model.n_steps} steps (its CFL step collapsed): "
                "velocities not measured (nan)"
            )
    rows = table_rows(meas, values, v, lead)
    print(format_table(rows))
    print(through_plate_warning(values, lead, "C_h = "))
    print(f"wall time {wall:.1f} s (compilation included)")
    csv_path = out / "ch_table.csv"
    with open(csv_path, "w") as f:
        f.write(
            "# debris-cloud feature velocities (km/s, downstream positive); jaxmpm at resolution "
            f"{args.resolution}, {args.fields} field(s), C_d = {args.drag}, fragmentation {args.fragmentation}, "
            f"drag heating {'on' if args.drag_heating else 'off'}, artificial viscosity "
            f"{tuple(args.artificial_viscosity)}, t_end = {model.t_end:g} s\n"
        )
        f.write("source,C_h,point_1,point_2,point_4,plate_lead_mm\n")
        for r in rows:
            lead_mm = "" if r.get("lead") is None else f"{1e3 * r['lead']:.4f}"
            f.write(
                f"{r['source']},{'' if r['C_h'] is None else r['C_h']},{r['v'][0]:.4f},{r['v'][1]:.4f},{r['v'][2]:.4f},"
                f"{lead_mm}\n"
            )
    png = plots.ch_table(rows, out / "ch_table.png")
    print(f"wrote:\n  {csv_path}\n  {png}")
    return 0


def table_rows(
    meas: Measurements, values: Sequence[float], v: np.ndarray, lead: np.ndarray | None = None
) -> list[dict[str, Any]]:
    """The table's rows (source, C_h, v (3,) km/s, lead m or None): the experiment, the seed's and
    jaxmpm's, v (len(values), 3), lead (len(values),) the plate's lead (`jaxmpm.features.plate_lead`) at t_end."""
    rows = [dict(source="experiment", C_h=None, v=meas.experiment, lead=None)]
    rows += [dict(source="seed", C_h=c, v=meas.seed[c], lead=None) for c in sorted(meas.seed)]
    leads = [None] * len(values) if lead is None else [float(x) for x in lead]
    rows += [dict(source="jaxmpm", C_h=c, v=vi, lead=li) for c, vi, li in zip(values, v, leads)]
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    """The table as text: velocities in km/s, the plate's lead in mm (jaxmpm's rows)."""
    lines = [f"{'source':<12}{'C_h':>8}{'point 1':>10}{'point 2':>10}{'point 4':>10}   (km/s){'plate lead':>14} (mm)"]
    for r in rows:
        ch = "" if r["C_h"] is None else f"{r['C_h']:g}"
        lead = "" if r.get("lead") is None else f"{1e3 * r['lead']:>14.2f}"
        lines.append(f"{r['source']:<12}{ch:>8}" + "".join(f"{x:>10.3f}" for x in r["v"]) + f"{'':9}{lead}")
    return "\n".join(lines)


def cmd_synthetic(args: argparse.Namespace) -> int:
    """Synthetic recovery on the small two-phase scene of calibration.synthetic: observables
    generated at (C_d, C_h) = --truth, the fit started at --start, recovered values printed."""
    jax.config.update("jax_enable_x64", True)
    truth, start = pair(args.truth, "--truth"), pair(args.start, "--start")
    iterations(args.iterations)
    out = new_folder(args.out)
    model = synthetic.DebrisInWaterModel.build()
    print(
        f"debris_in_water: {model.state.x.shape[0]} particles, {model.n_steps} steps to {model.scene.t_end:g} s; "
        f"truth C_d = {truth[0]:g}, C_h = {truth[1]:g}; start C_d = {start[0]:g}, C_h = {start[1]:g}",
        flush=True,
    )
    target = jit(model.observables)(theta_of(*truth))
    res = fitting.fit(
        model.observables,
        target,
        theta_of(*start),
        iterations=args.iterations,
        method=args.method,
        tol=1e-12,
        progress=not args.no_progress,
    )
    err = res.values / np.asarray(truth) - 1
    print(f"stopped: {res.stopped} ({len(res.history)} iterations, {res.evaluations} evaluations, {res.seconds:.1f} s)")
    print(
        f"recovered C_d = {res.values[0]:.6g} ({100 * err[0]:+.2g}%), C_h = {res.values[1]:.6g} ({100 * err[1]:+.2g}%)"
    )
    result = dict(
        truth=dict(C_d=truth[0], C_h=truth[1]),
        start=dict(C_d=start[0], C_h=start[1]),
        recovered=dict(C_d=float(res.values[0]), C_h=float(res.values[1])),
        relative_error=dict(C_d=float(err[0]), C_h=float(err[1])),
        loss=res.loss,
        stopped=res.stopped,
        history=res.history,
        observables=np.asarray(target).tolist(),
        settings=dict(
            scene=model.scene.name,
            particles=int(model.state.x.shape[0]),
            n_steps=model.n_steps,
            t_end=model.scene.t_end,
            iterations=args.iterations,
            method=args.method,
            evaluations=res.evaluations,
            wall_seconds=res.seconds,
            argv=sys.argv,
        ),
        versions=versions(),
    )
    (out / "result.json").write_text(json.dumps(result, indent=1))
    print(f"wrote:\n  {out / 'result.json'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    # longer than 60 lines on purpose: one declaration per command and flag, in the order --help lists them
    ap = argparse.ArgumentParser(
        prog="python -m calibration", description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument(
        "--no-cache",
        action="store_true",
        help="no persistent compilation cache (default: on, in "
        "~/.cache/jaxmpm/xla or $JAXMPM_CACHE_DIR; JAXMPM_NO_CACHE=1 also turns it off)",
    )
    sub = ap.add_subparsers(dest="command", required=True)
    for name, fn, default_out in (("table", cmd_table, "calibration_table"), ("fit", cmd_fit, "calibration_fit")):
        p = sub.add_parser(
            name,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
            help={
                "table": "the debris cloud's feature velocities for a list of C_h, against the experiment",
                "fit": "fit (C_d, C_h) to the experiment's feature velocities by gradient descent",
            }[name],
        )
        p.set_defaults(fn=fn)
        p.add_argument("--resolution", type=float, default=0.75, help="debris_cloud resolution (>= 0.724)")
        p.add_argument(
            "--fields",
            type=int,
            default=2 if name == "fit" else 1,
            help="velocity fields (2 for fit: C_d acts between them; 1 or 2 for table)",
        )
        p.add_argument("--t-end", type=float, default=6e-6, help="end time, s (velocities over the later half)")
        p.add_argument("--data", default=None, help="the experiment's CSV (None: the packaged copy)")
        p.add_argument("--out", default=default_out, help="output folder (must not hold a previous result)")
        p.add_argument(
            "--fragmentation",
            choices=("failed", "plastic", "tensile"),
            default="failed",
            help="what the closure counts as fragmented: failed material's plastic strain (failed), "
            "all plastic strain (plastic: the seed's E5) or plastic strain accrued in tension, with the "
            "compressive pressure kept (tensile); see docs/closure.md",
        )
        p.add_argument(
            "--drag-heating",
            action="store_true",
            help="book the drag's work as heat (Scene.drag_heating; "
            "only with --fields 2): the run keeps its energy, and the fitted C_d, C_h change",
        )
        p.add_argument(
            "--artificial-viscosity",
            type=float,
            nargs=2,
            metavar=("C_LINEAR", "C_QUADRATIC"),
            default=list(DEBRIS_VISCOSITY),
            help="the debris cloud's artificial viscosity coefficients (debris_cloud's artificial_viscosity; "
            "AUTODYN's default is 0.2 1.0); see docs/closure.md for what they do to the cloud's front",
        )
        p.add_argument(
            "--step-safety",
            type=float,
            default=2.0,
            help="scan steps as a multiple (>= 1) of the initial CFL estimate: the step shrinks as the "
            "cloud heats and jets (fragmentation tensile at resolution >= 1.5 needs ~8)",
        )
        p.add_argument(
            "--float32",
            action="store_true",
            help="run in float32 (otherwise float64: float32 adjoints of the two-field cloud overflow past ~2 us)",
        )
    t = sub.choices["table"]
    t.add_argument(
        "--c-h", default=",".join(map(str, SEED_CH)), help="C_h values (comma-separated; the default is the seed's)"
    )
    t.add_argument("--drag", type=float, default=1.0, help="C_d > 0 (used with --fields 2)")
    f = sub.choices["fit"]
    f.add_argument("--iterations", type=int, default=30, help="optimiser iterations")
    f.add_argument("--start", default="1.0,0.15", help="starting C_d,C_h")
    f.add_argument(
        "--starts",
        type=int,
        default=1,
        help="K >= 1 starting points, advanced together in one vmapped call (adam): --start, then K - 1 "
        "Halton points over the landscape's log-spaced C_d x C_h box; the best kept, all reported",
    )
    f.add_argument(
        "--method",
        choices=("adam", "lbfgs"),
        default="adam",
        help="optimiser: adam (robust from a poor start) or lbfgs (line search; few iterations near the optimum)",
    )
    f.add_argument("--learning-rate", type=float, default=0.15, help="Adam step in log space (> 0)")
    f.add_argument("--landscape", type=int, default=4, help="N >= 2: an N x N landscape grid (0: none)")
    f.add_argument(
        "--landscape-cd",
        type=float,
        nargs=2,
        default=(0.1, 10.0),
        metavar=("LO", "HI"),
        help="the landscape's C_d range (log-spaced)",
    )
    f.add_argument(
        "--landscape-ch",
        type=float,
        nargs=2,
        default=(0.02, 1.0),
        metavar=("LO", "HI"),
        help="the landscape's C_h range (log-spaced)",
    )
    f.add_argument("--no-progress", action="store_true", help="no progress bars")
    y = sub.add_parser(
        "synthetic",
        help="recover known (C_d, C_h) on a small two-phase scene (about a minute)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    y.set_defaults(fn=cmd_synthetic)
    y.add_argument("--truth", default="1.0,0.15", help="C_d,C_h that generate the observables")
    y.add_argument("--start", default="2.0,0.3", help="starting C_d,C_h")
    y.add_argument("--iterations", type=int, default=20, help="optimiser iterations")
    y.add_argument("--method", choices=("adam", "lbfgs"), default="lbfgs", help="optimiser")
    y.add_argument(
        "--out", default="calibration_synthetic", help="output folder for result.json (must not hold a previous result)"
    )
    y.add_argument("--no-progress", action="store_true", help="no progress bars")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not args.no_cache:
        compile_cache.enable()  # before anything compiles: a second start reads the programs back
    try:
        return args.fn(args)
    except (ValueError, FileExistsError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
