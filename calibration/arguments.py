"""The calibration commands' checks of their arguments (each a ValueError naming the flag and what
is allowed), their output folder, the measurements they read and the model they build."""

from __future__ import annotations

import argparse
import os
import platform
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np
import optax

import jaxmpm
from calibration import data
from calibration.model import CloudModel


def new_folder(out: str | os.PathLike) -> Path:
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


def pair(text: str, flag: str) -> tuple[float, float]:
    """The two positive finite numbers (C_d, C_h) of a flag's 'C_d,C_h' text."""
    try:
        c_d, c_h = (float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"{flag} {text!r} is invalid: allowed two numbers 'C_d,C_h', e.g. 2.0,0.3") from None
    if not (0 < c_d < np.inf and 0 < c_h < np.inf):
        raise ValueError(f"{flag} {text!r} is invalid: allowed C_d > 0 and C_h > 0 (finite)")
    return c_d, c_h


def c_h_values(text: str, flag: str) -> list[float]:
    """The comma-separated C_h values of --c-h, each finite and > 0."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"{flag} {text!r} is invalid: allowed comma-separated numbers, e.g. 0.02,0.15,0.5") from None
    if not all(0 < v < np.inf for v in values):
        raise ValueError(f"{flag} {text!r} is invalid: allowed C_h values > 0 (finite)")
    return values


def positive(value: float, flag: str, what: str = "") -> float:
    """value if it is finite and > 0."""
    if not 0 < value < np.inf:
        raise ValueError(f"{flag} {value} is invalid: allowed a finite number > 0{what}")
    return value


def iterations(n: int) -> int:
    """n if it is an integer >= 1 (--iterations)."""
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"--iterations {n} is invalid: allowed an integer >= 1")
    return n


def bounds(lo_hi: Sequence[float], flag: str) -> tuple[float, float]:
    """(LO, HI) of a landscape axis: 0 < LO < HI, finite."""
    lo, hi = lo_hi
    if not 0 < lo < hi < np.inf:
        raise ValueError(f"{flag} {lo} {hi} is invalid: allowed LO HI with 0 < LO < HI (finite)")
    return lo, hi


def scene_options(args: argparse.Namespace) -> dict[str, Any]:
    """The debris_cloud scene's keyword options that the arguments set (resolution, fields, t_end,
    fragmentation, drag_heating, artificial_viscosity)."""
    return dict(
        resolution=args.resolution,
        fields=args.fields,
        t_end=args.t_end,
        fragmentation=args.fragmentation,
        drag_heating=args.drag_heating,
        artificial_viscosity=tuple(args.artificial_viscosity),
    )


def check_scene(args: argparse.Namespace, fields: tuple[int, ...]) -> None:
    """Refuse a bad --fields, --t-end or --resolution before any work; the debris_cloud scene, built
    here without arrays (milliseconds), checks what remains: the resolution's lower bound."""
    if args.fields not in fields:
        raise ValueError(
            f"--fields {args.fields} is invalid: allowed {' | '.join(map(str, fields))}"
            + ("" if 1 in fields else " (C_d, the drag between the two velocity fields, has no effect with one field)")
        )
    positive(args.t_end, "--t-end", " (s)")
    positive(args.resolution, "--resolution")
    if not (args.step_safety >= 1 and args.step_safety < np.inf):
        raise ValueError(f"--step-safety {args.step_safety} is invalid: allowed a finite number >= 1")
    try:
        jaxmpm.load_scene("debris_cloud", **scene_options(args))
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


def measurements(path: str | os.PathLike | None) -> data.Measurements:
    """data.load(path); a missing, unreadable or bad table a usage error naming --data (data.load's
    messages start with the path)."""
    try:
        return data.load(path)
    except (ValueError, FileNotFoundError) as e:
        raise ValueError(f"--data {e}" if path is not None else str(e)) from None
    except OSError as e:
        raise ValueError(f"--data {path}: the file cannot be read ({e.strerror or e})") from None


def versions() -> dict[str, str]:
    """The versions of Python, JAX, optax, jaxmpm and NumPy, and JAX's backend, for result.json."""
    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "optax": optax.__version__,
        "jaxmpm": jaxmpm.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
    }


def setup_model(args: argparse.Namespace) -> CloudModel:
    """The debris-cloud model of the arguments (--float32 off: float64 switched on first)."""
    if not args.float32:
        jax.config.update("jax_enable_x64", True)
    return CloudModel.build(safety=args.step_safety, **scene_options(args))


def model_header(args: argparse.Namespace, model: CloudModel) -> str:
    """The line a command prints before its runs: the scene, its particles and its steps."""
    return (
        f"debris_cloud: resolution {args.resolution}, {args.fields} field(s), {model.state.x.shape[0]} particles, "
        f"{model.n_steps} steps to {model.t_end:g} s"
    )
