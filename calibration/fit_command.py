"""`python -m calibration fit`: the fit of (C_d, C_h) to the experiment's feature velocities, from
one start or several advanced together, its standard errors, the loss landscape and result.json."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import numpy as np

from calibration import fit as fitting
from calibration import plots
from calibration.arguments import (
    bounds,
    check_scene,
    iterations,
    measurements,
    model_header,
    new_folder,
    pair,
    scene_options,
    positive,
    setup_model,
    versions,
)
from calibration.data import Measurements
from calibration.fit import FitResult
from calibration.model import CloudModel, theta_of, through_plate_warning


def check_fit_args(args: argparse.Namespace) -> tuple[float, float]:
    """The starting (C_d, C_h) of --start, after every check of fit's arguments that needs no scene."""
    start = pair(args.start, "--start")
    iterations(args.iterations)
    if not (isinstance(args.starts, int) and args.starts >= 1):
        raise ValueError(f"--starts {args.starts} is invalid: allowed an integer >= 1")
    if args.starts > 1 and args.method != "adam":
        raise ValueError(
            f"--starts {args.starts} is invalid with --method {args.method}: allowed only with --method adam "
            "(the starts advance together, one vmapped step each)"
        )
    positive(args.learning_rate, "--learning-rate", " (Adam's step in log space)")
    if not (args.landscape == 0 or args.landscape >= 2):
        raise ValueError(f"--landscape {args.landscape} is invalid: allowed 0 (none) or an integer >= 2")
    bounds(args.landscape_cd, "--landscape-cd")
    bounds(args.landscape_ch, "--landscape-ch")
    check_scene(args, fields=(2,))
    return start


def fit_from_starts(
    args: argparse.Namespace, model: CloudModel, meas: Measurements, start: tuple[float, float]
) -> tuple[FitResult, list[dict[str, Any]] | None]:
    """(the fit, the starts' table or None): one fit from --start, or --starts K advanced together
    (one vmapped call), the best kept."""
    starts = None
    if args.starts == 1:
        res = fitting.fit(
            model.velocities,
            meas.experiment,
            theta_of(*start),
            iterations=args.iterations,
            learning_rate=args.learning_rate,
            progress=not args.no_progress,
            method=args.method,
        )
    else:
        thetas = fitting.spread_starts(start, args.starts, args.landscape_cd, args.landscape_ch)
        multi = fitting.fit_starts(
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
    return res, starts


def fit_result(
    args: argparse.Namespace,
    model: CloudModel,
    meas: Measurements,
    start: tuple[float, float],
    res: FitResult,
    starts: list[dict[str, Any]] | None,
    errors: tuple[np.ndarray, np.ndarray, np.ndarray, float],
    checks: tuple[float, float],
    land: dict[str, list] | None,
    wall: float,
) -> dict[str, Any]:
    """result.json's content: the fitted values with their standard errors (errors: those of
    `fit.standard_errors`), the residuals, the history, the starts, the landscape (land: C_d, C_h and
    loss lists, or None), the checks at the fit (`CloudModel.checks`: the time reached (s) and the
    plate's lead (m), `jaxmpm.features.plate_lead`) and the settings; wall: seconds."""
    se_theta, se, J, cond = errors
    reached, lead = checks
    c_d, c_h = res.values
    fitted = meas.experiment + res.residuals
    return dict(
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
        plate_lead_mm=1e3 * lead,
        points=list(meas.points),
        experiment_km_s=meas.experiment.tolist(),
        fitted_km_s=fitted.tolist(),
        residuals_km_s=res.residuals.tolist(),
        max_abs_residual_km_s=float(np.max(np.abs(res.residuals))),
        history=res.history,
        starts=starts,
        landscape=land,
        settings=fit_settings(args, model, meas, start, res, wall),
        versions=versions(),
    )


def fit_settings(
    args: argparse.Namespace,
    model: CloudModel,
    meas: Measurements,
    start: tuple[float, float],
    res: FitResult,
    wall: float,
) -> dict[str, Any]:
    """result.json's settings: the scene's and the fit's options, the steps, the particles, the
    data file, the wall time (s) and the command line."""
    return dict(
        scene_options(args),
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
    )


def cmd_fit(args: argparse.Namespace) -> int:
    """`python -m calibration fit`: the fit, printed and written to --out (result.json, figures)."""
    start = check_fit_args(args)
    meas = measurements(args.data)
    out = new_folder(args.out)
    model = setup_model(args)
    print(f"{model_header(args, model)}; start C_d = {start[0]:g}, C_h = {start[1]:g}", flush=True)
    t0 = time.perf_counter()
    res, starts = fit_from_starts(args, model, meas, start)
    se_theta, se, J, cond = fitting.standard_errors(model.velocities, res.theta, res.residuals)
    c_d, c_h = res.values
    print(f"stopped: {res.stopped} ({len(res.history)} iterations, {res.evaluations} loss-and-gradient evaluations)")
    reached, lead = model.checks(res.theta, progress=not args.no_progress)
    print(
        through_plate_warning(["the fit"], [lead])
        if lead < 0
        else f"plate lead {1e3 * lead:.2f} mm (the plate's debris leads, as in the experiment)"
    )
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
        loss, _ = fitting.landscape(
            lambda th: model.velocities_batch(th, allow_short=True, progress=not args.no_progress),
            meas.experiment,
            cds,
            chs,
        )
        land = dict(C_d=cds.tolist(), C_h=chs.tolist(), loss=loss.tolist())
    wall = time.perf_counter() - t0
    result = fit_result(args, model, meas, start, res, starts, (se_theta, se, J, cond), (reached, lead), land, wall)
    (out / "result.json").write_text(json.dumps(result, indent=1))
    pngs = plots.fit_report(result, out)
    print(f"wall time {wall:.1f} s\nwrote:\n  {out / 'result.json'}" + "".join(f"\n  {p}" for p in pngs))
    return 0
