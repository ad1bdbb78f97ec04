"""python -m calibration {table,fit,synthetic} ...: the debris cloud's feature velocities against C_h (table),
the fit of (C_d, C_h) to the experiment (fit), the recovery of known (C_d, C_h) (synthetic); see
calibration/__init__.py."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np
import optax

import jaxmpm
from calibration import data, plots
from calibration import fit as F
from calibration.model import CloudModel, theta_of
from calibration import synthetic
from jaxmpm.run import compile_cache
from jaxmpm.scenes.impact import DEBRIS_VISCOSITY
from jaxmpm.numerics.compile import jit

SEED_CH = (0.02, 0.15, 0.5, 1.0)


def _new_folder(out) -> Path:
    """The output folder, created; refuses one that holds a previous result, and a path through a file."""
    out = Path(out)
    blocker = next((p for p in (out, *out.parents) if p.exists() and not p.is_dir()), None)
    if blocker is not None:
        raise ValueError(
            f"--out {out} is invalid: {blocker} exists and is not a folder (allowed a new folder or an empty one)"
        )
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(
            f"--out {out}: the folder exists and is not empty: a previous result is never "
            "overwritten (choose a new folder or remove it yourself)"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"--out {out}: the folder cannot be created ({e.strerror or e})") from None
    return out


def _pair(text, flag):
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"{flag} {text!r} is invalid: allowed two numbers 'C_d,C_h', e.g. 2.0,0.3") from None
    if not (0 < a < np.inf and 0 < b < np.inf):
        raise ValueError(f"{flag} {text!r} is invalid: allowed C_d > 0 and C_h > 0 (finite)")
    return a, b


def _values(text, flag):
    """The comma-separated C_h values of --c-h, each finite and > 0."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"{flag} {text!r} is invalid: allowed comma-separated numbers, e.g. 0.02,0.15,0.5") from None
    if not all(0 < v < np.inf for v in values):
        raise ValueError(f"{flag} {text!r} is invalid: allowed C_h values > 0 (finite)")
    return values


def _positive(value, flag, what=""):
    """value if it is finite and > 0."""
    if not 0 < value < np.inf:
        raise ValueError(f"{flag} {value} is invalid: allowed a finite number > 0{what}")
    return value


def _iterations(n):
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"--iterations {n} is invalid: allowed an integer >= 1")
    return n


def _bounds(lo_hi, flag):
    """(LO, HI) of a landscape axis: 0 < LO < HI, finite."""
    lo, hi = lo_hi
    if not 0 < lo < hi < np.inf:
        raise ValueError(f"{flag} {lo} {hi} is invalid: allowed LO HI with 0 < LO < HI (finite)")
    return lo, hi


def _check_scene(args, fields):
    """Refuse a bad --fields, --t-end or --resolution before any work; the debris_cloud scene, built
    here without arrays (milliseconds), checks what remains: the resolution's lower bound."""
    if args.fields not in fields:
        raise ValueError(
            f"--fields {args.fields} is invalid: allowed {' | '.join(map(str, fields))}"
            + ("" if 1 in fields else " (C_d, the drag between the two velocity fields, has no effect with one field)")
        )
    _positive(args.t_end, "--t-end", " (s)")
    _positive(args.resolution, "--resolution")
    if not (args.step_safety >= 1 and args.step_safety < np.inf):
        raise ValueError(f"--step-safety {args.step_safety} is invalid: allowed a finite number >= 1")
    try:
        jaxmpm.load_scene(
            "debris_cloud",
            resolution=args.resolution,
            fields=args.fields,
            t_end=args.t_end,
            fragmentation=args.fragmentation,
            drag_heating=args.drag_heating,
            artificial_viscosity=tuple(args.artificial_viscosity),
        )
    except ValueError as e:
        if args.drag_heating and args.fields != 2:
            raise ValueError(
                f"--drag-heating is invalid with --fields {args.fields}: allowed only with --fields 2 "
                "(the heat is the drag's work between the two fields)"
            ) from None
        if "artificial_viscosity" in str(e):
            raise ValueError(
                f"--artificial-viscosity {' '.join(map(str, args.artificial_viscosity))} is invalid: allowed "
                "two finite numbers >= 0 (C_LINEAR C_QUADRATIC)"
            ) from None
        raise ValueError(f"--resolution {args.resolution} is invalid: {e}") from None


def _measurements(path):
    """data.load(path); a missing, unreadable or bad table a usage error naming --data (data.load's
    messages start with the path)."""
    try:
        return data.load(path)
    except (ValueError, FileNotFoundError) as e:
        raise ValueError(f"--data {e}" if path is not None else str(e)) from None
    except OSError as e:
        raise ValueError(f"--data {path}: the file cannot be read ({e.strerror or e})") from None


def _versions():

    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "optax": optax.__version__,
        "jaxmpm": jaxmpm.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
    }


def _setup(args):
    if not args.float32:
        jax.config.update("jax_enable_x64", True)
    return CloudModel.build(
        resolution=args.resolution,
        fields=args.fields,
        t_end=args.t_end,
        safety=args.step_safety,
        fragmentation=args.fragmentation,
        drag_heating=args.drag_heating,
        artificial_viscosity=tuple(args.artificial_viscosity),
    )


def cmd_table(args) -> int:
    values = _values(args.c_h, "--c-h")
    _positive(args.drag, "--drag", " (C_d)")
    _check_scene(args, fields=(1, 2))
    meas = _measurements(args.data)
    out = _new_folder(args.out)
    model = _setup(args)
    print(
        f"debris_cloud: resolution {args.resolution}, {args.fields} field(s), {model.state.x.shape[0]} particles, "
        f"{model.n_steps} steps to {model.t_end:g} s; C_h = {values} in one vmapped call",
        flush=True,
    )
    t0 = time.perf_counter()
    thetas = np.log(np.stack([np.full(len(values), args.drag), values], -1))
    v = np.asarray(model.velocities_batch(thetas, allow_short=True))
    wall = time.perf_counter() - t0
    for c, vi in zip(values, v):
        if np.isnan(vi).any():
            print(
                f"C_h = {c:g}: the run did not reach t_end in {model.n_steps} steps (its CFL step collapsed): "
                "velocities not measured (nan)"
            )
    rows = table_rows(meas, values, v)
    print(format_table(rows))
    print(f"wall time {wall:.1f} s (compilation included)")
    csv_path = out / "ch_table.csv"
    with open(csv_path, "w") as f:
        f.write(
            "# debris-cloud feature velocities (km/s, downstream positive); jaxmpm at resolution "
            f"{args.resolution}, {args.fields} field(s), C_d = {args.drag}, fragmentation {args.fragmentation}, "
            f"drag heating {'on' if args.drag_heating else 'off'}, artificial viscosity "
            f"{tuple(args.artificial_viscosity)}, t_end = {model.t_end:g} s\n"
        )
        f.write("source,C_h,point_1,point_2,point_4\n")
        for r in rows:
            f.write(
                f"{r['source']},{'' if r['C_h'] is None else r['C_h']},{r['v'][0]:.4f},{r['v'][1]:.4f},{r['v'][2]:.4f}\n"
            )
    png = plots.ch_table(rows, out / "ch_table.png")
    print(f"wrote:\n  {csv_path}\n  {png}")
    return 0


def table_rows(meas, values, v):
    rows = [dict(source="experiment", C_h=None, v=meas.experiment)]
    rows += [dict(source="seed", C_h=c, v=meas.seed[c]) for c in sorted(meas.seed)]
    rows += [dict(source="jaxmpm", C_h=c, v=vi) for c, vi in zip(values, v)]
    return rows


def format_table(rows) -> str:
    lines = [f"{'source':<12}{'C_h':>8}{'point 1':>10}{'point 2':>10}{'point 4':>10}   (km/s)"]
    for r in rows:
        ch = "" if r["C_h"] is None else f"{r['C_h']:g}"
        lines.append(f"{r['source']:<12}{ch:>8}" + "".join(f"{x:>10.3f}" for x in r["v"]))
    return "\n".join(lines)


def cmd_fit(args) -> int:
    start = _pair(args.start, "--start")
    _iterations(args.iterations)
    if not (isinstance(args.starts, int) and args.starts >= 1):
        raise ValueError(f"--starts {args.starts} is invalid: allowed an integer >= 1")
    if args.starts > 1 and args.method != "adam":
        raise ValueError(
            f"--starts {args.starts} is invalid with --method {args.method}: allowed only with --method adam "
            "(the starts advance together, one vmapped step each)"
        )
    _positive(args.learning_rate, "--learning-rate", " (Adam's step in log space)")
    if not (args.landscape == 0 or args.landscape >= 2):
        raise ValueError(f"--landscape {args.landscape} is invalid: allowed 0 (none) or an integer >= 2")
    _bounds(args.landscape_cd, "--landscape-cd")
    _bounds(args.landscape_ch, "--landscape-ch")
    _check_scene(args, fields=(2,))
    meas = _measurements(args.data)
    out = _new_folder(args.out)
    model = _setup(args)
    print(
        f"debris_cloud: resolution {args.resolution}, {args.fields} fields, {model.state.x.shape[0]} particles, "
        f"{model.n_steps} steps to {model.t_end:g} s; start C_d = {start[0]:g}, C_h = {start[1]:g}",
        flush=True,
    )
    t0 = time.perf_counter()
    starts = None
    if args.starts == 1:
        res = F.fit(
            model.velocities,
            meas.experiment,
            theta_of(*start),
            iterations=args.iterations,
            learning_rate=args.learning_rate,
            progress=not args.no_progress,
            method=args.method,
        )
    else:
        thetas = F.spread_starts(start, args.starts, args.landscape_cd, args.landscape_ch)
        multi = F.fit_starts(
            model.velocities,
            meas.experiment,
            thetas,
            iterations=args.iterations,
            learning_rate=args.learning_rate,
            progress=not args.no_progress,
        )
        res = multi.best_fit
        starts = [
            dict(
                start_C_d=float(np.exp(th[0])),
                start_C_h=float(np.exp(th[1])),
                C_d=float(f.values[0]),
                C_h=float(f.values[1]),
                loss=f.loss,
                residuals_km_s=np.asarray(f.residuals).tolist(),
                iterations=len(f.history),
                stopped=f.stopped,
                best=k == multi.best,
            )
            for k, (th, f) in enumerate(zip(thetas, multi.fits))
        ]
        print(f"{args.starts} starts in one vmapped call ({multi.seconds:.1f} s); the best kept (*):")
        print(f"{'':2}{'start C_d':>10}{'start C_h':>10}{'C_d':>10}{'C_h':>10}{'loss':>11}{'its':>5}")
        for s in starts:
            print(
                f"{'*' if s['best'] else '':2}{s['start_C_d']:>10.4g}{s['start_C_h']:>10.4g}{s['C_d']:>10.4g}"
                f"{s['C_h']:>10.4g}{s['loss']:>11.4g}{s['iterations']:>5}"
            )
    se_theta, se, J, cond = F.standard_errors(model.velocities, res.theta, res.residuals)
    c_d, c_h = res.values
    print(f"stopped: {res.stopped} ({len(res.history)} iterations, {res.evaluations} loss-and-gradient evaluations)")
    reached = model.reached(res.theta, progress=not args.no_progress)
    if reached < model.t_end * (1 - 1e-6):
        print(
            f"warning: at the fit the run reaches only t = {reached:.4g} s of {model.t_end:g} s in {model.n_steps} "
            "steps (its CFL step collapsed): the fitted velocities are not measured over the intended window"
        )
    print(f"C_d = {c_d:.4g} +- {se[0]:.2g}, C_h = {c_h:.4g} +- {se[1]:.2g} (Gauss-Newton, cond(J^T J) = {cond:.3g})")
    fitted = meas.experiment + res.residuals
    print(f"{'point':<8}{'experiment':>12}{'fit':>10}{'residual':>10}{'seed C_h=0.02':>15}")
    for i, p in enumerate(meas.points):
        seed = meas.seed.get(0.02, np.full(3, np.nan))[i]
        print(f"{p:<8}{meas.experiment[i]:>12.3f}{fitted[i]:>10.3f}{res.residuals[i]:>10.3f}{seed:>15.3f}")
    land = None
    if args.landscape >= 2:
        cds = np.geomspace(args.landscape_cd[0], args.landscape_cd[1], args.landscape)
        chs = np.geomspace(args.landscape_ch[0], args.landscape_ch[1], args.landscape)
        loss, _ = F.landscape(
            lambda th: model.velocities_batch(th, allow_short=True, progress=not args.no_progress),
            meas.experiment,
            cds,
            chs,
        )
        land = dict(C_d=cds.tolist(), C_h=chs.tolist(), loss=loss.tolist())
    wall = time.perf_counter() - t0
    result = dict(
        fitted=dict(
            C_d=float(c_d),
            C_h=float(c_h),
            se_C_d=float(se[0]),
            se_C_h=float(se[1]),
            se_log_C_d=float(se_theta[0]),
            se_log_C_h=float(se_theta[1]),
            jacobian_km_s=J.tolist(),
            condition_JtJ=cond,
        ),
        loss=res.loss,
        stopped=res.stopped,
        reached_t_end=bool(reached >= model.t_end * (1 - 1e-6)),
        points=list(meas.points),
        experiment_km_s=meas.experiment.tolist(),
        fitted_km_s=fitted.tolist(),
        residuals_km_s=res.residuals.tolist(),
        max_abs_residual_km_s=float(np.max(np.abs(res.residuals))),
        history=res.history,
        starts=starts,
        landscape=land,
        settings=dict(
            resolution=args.resolution,
            fields=args.fields,
            fragmentation=args.fragmentation,
            drag_heating=args.drag_heating,
            artificial_viscosity=list(args.artificial_viscosity),
            t_end=model.t_end,
            n_steps=model.n_steps,
            particles=int(model.state.x.shape[0]),
            start=list(start),
            starts=args.starts,
            iterations=args.iterations,
            method=args.method,
            evaluations=res.evaluations,
            learning_rate=args.learning_rate,
            float32=args.float32,
            data=meas.source,
            wall_seconds=wall,
            argv=sys.argv,
        ),
        versions=_versions(),
    )
    (out / "result.json").write_text(json.dumps(result, indent=1))
    pngs = plots.fit_report(result, out)
    print(f"wall time {wall:.1f} s\nwrote:\n  {out / 'result.json'}" + "".join(f"\n  {p}" for p in pngs))
    return 0


def cmd_synthetic(args) -> int:
    """Synthetic recovery on the small two-phase scene of calibration.synthetic: observables
    generated at (C_d, C_h) = --truth, the fit started at --start, recovered values printed."""
    jax.config.update("jax_enable_x64", True)
    truth, start = _pair(args.truth, "--truth"), _pair(args.start, "--start")
    _iterations(args.iterations)
    out = _new_folder(args.out)
    model = synthetic.DebrisInWaterModel.build()
    print(
        f"debris_in_water: {model.state.x.shape[0]} particles, {model.n_steps} steps to {model.scene.t_end:g} s; "
        f"truth C_d = {truth[0]:g}, C_h = {truth[1]:g}; start C_d = {start[0]:g}, C_h = {start[1]:g}",
        flush=True,
    )
    target = jit(model.observables)(theta_of(*truth))
    res = F.fit(
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
        versions=_versions(),
    )
    (out / "result.json").write_text(json.dumps(result, indent=1))
    print(f"wrote:\n  {out / 'result.json'}")
    return 0


def build_parser():
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


def main(argv=None) -> int:
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
