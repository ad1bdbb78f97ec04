"""The checks of `fit`'s and `fit_starts`' arguments, each a ValueError naming the argument, its
value and what is allowed, before any run; and the type of the forward model they fit."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

# theta (2,) -> observables (3,) km/s (or any shape): the forward model the fit differentiates
Observables = Callable[[jax.Array], jax.Array]

METHODS = ("adam", "lbfgs")


def _real(value: Any) -> float:
    """value as a float; nan where it is not a real number (a string, an array of several)."""
    if isinstance(value, (str, bytes)):
        return np.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return np.nan


def _float_array(value: Any) -> np.ndarray | None:
    """value as a float array; None where it is not numeric."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None


def _require(ok: bool, name: str, value: Any, allowed: str) -> None:
    """A ValueError naming the argument, its value and what is allowed, unless ok."""
    if not ok:
        raise ValueError(f"{name} = {value!r} is invalid: allowed {allowed}")


def check_options(
    iterations: int, learning_rate: float, decay: float, tol: float, rtol: float, patience: int, method: str
) -> None:
    """Refuse out-of-range scalar options of `fit` (ValueError naming the option and its range)."""
    integer = lambda x: isinstance(x, (int, np.integer)) and not isinstance(x, bool)
    _require(integer(iterations) and iterations >= 1, "iterations", iterations, "an integer >= 1")
    _require(method in METHODS, "method", method, " | ".join(METHODS))
    rate, factor, absolute, relative = _real(learning_rate), _real(decay), _real(tol), _real(rtol)
    _require(
        np.isfinite(rate) and rate > 0, "learning_rate", learning_rate, "a finite number > 0 (Adam's step in log space)"
    )
    _require(
        0 < factor <= 1, "decay", decay, "a number in (0, 1] (the learning rate's factor per iteration; 1: constant)"
    )
    _require(np.isfinite(absolute) and absolute >= 0, "tol", tol, "a finite number >= 0 (km/s)^2")
    _require(np.isfinite(relative) and relative >= 0, "rtol", rtol, "a finite number >= 0")
    _require(integer(patience) and patience >= 1, "patience", patience, "an integer >= 1")


def check_arrays(
    velocities: Observables, target: ArrayLike, theta0: ArrayLike, weights: ArrayLike | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(target, theta0, weights) as float arrays, checked: theta0 finite (2,); target finite, of the
    shape of velocities(theta0) (found by tracing, without running it); weights None or finite,
    >= 0, not all 0, of target's shape. ValueError naming the argument otherwise."""
    start = _float_array(theta0)
    _require(
        start is not None and start.shape == (2,) and np.all(np.isfinite(start)),
        "theta0",
        theta0,
        "finite numbers of shape (2,): (log C_d, log C_h)",
    )
    measured = _float_array(target)
    _require(measured is not None and np.all(np.isfinite(measured)), "target", target, "finite numbers (km/s)")
    shape = jax.eval_shape(velocities, jnp.asarray(start, jnp.zeros(()).dtype)).shape
    if measured.shape != shape:
        raise ValueError(
            f"target of shape {measured.shape} is invalid: allowed the shape of velocities(theta0), {shape}"
        )
    if weights is None:
        return measured, start, None
    weight = _float_array(weights)
    _require(
        weight is not None
        and weight.shape == measured.shape
        and np.all(np.isfinite(weight) & (weight >= 0))
        and np.any(weight > 0),
        "weights",
        weights,
        f"None or finite numbers >= 0, not all 0, of target's shape {measured.shape}",
    )
    return measured, start, weight


def check_starts(theta0s: ArrayLike) -> np.ndarray:
    """theta0s as a float array (K, 2) of finite starting points, K >= 1; ValueError otherwise."""
    starts = _float_array(theta0s)
    _require(
        starts is not None
        and starts.ndim == 2
        and starts.shape[0] >= 1
        and starts.shape[1] == 2
        and np.all(np.isfinite(starts)),
        "theta0s",
        theta0s,
        "finite numbers of shape (K, 2), K >= 1: K starting points (log C_d, log C_h)",
    )
    return starts
