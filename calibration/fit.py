"""Gradient-descent fit of (C_d, C_h) to the measured feature velocities, its standard errors,
and the loss landscape.

Loss (km/s)^2: L(theta) = sum_i w_i (v_i(theta) - v_i^exp)^2 over points 1, 2, 4, with
theta = (log C_d, log C_h) and weights w (default 1). Optimisers (optax): 'adam', Adam with an
exponentially decaying learning rate (robust from a poor start; one value-and-gradient per
iteration), or 'lbfgs', L-BFGS with a zoom line search (Wolfe conditions; it converges in a few
iterations once the loss is smooth near the optimum, at one or more value-and-gradient evaluations
per iteration, counted in `evaluations`). Both stop early when the loss falls below `tol` or
changes by less than `rtol` relative over `patience` iterations. The best iterate is returned
(not the last).

Standard errors (Gauss-Newton): with J = d v / d theta (3 x 2, forward mode) at the fit and
s^2 = sum_i w_i r_i^2 / (n - p) (n = 3 points, p = 2), Cov(theta) = s^2 (J^T W J)^-1; for
C = exp(theta) the delta method gives se(C) = C se(theta).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.typing import ArrayLike
from tqdm.auto import tqdm

from calibration.fit_checks import METHODS as METHODS, Observables, check_arrays, check_options, check_starts
from jaxmpm.numerics.compile import jit


def loss_fn(
    velocities: Observables, target: ArrayLike, weights: ArrayLike | None = None
) -> Callable[[jax.Array], tuple[jax.Array, jax.Array]]:
    """theta (2,) -> weighted sum of squared residuals (km/s)^2, and the residuals (3,); target and
    weights (3,)."""
    target = jnp.asarray(target)
    weight = jnp.ones_like(target) if weights is None else jnp.asarray(weights, target.dtype)

    def loss(theta: jax.Array) -> tuple[jax.Array, jax.Array]:
        residuals = velocities(theta) - target
        return jnp.sum(weight * residuals * residuals), residuals

    return loss


@dataclass
class FitResult:
    theta: np.ndarray  # (2,) best (log C_d, log C_h)
    loss: float  # at theta, (km/s)^2
    residuals: np.ndarray  # (3,) km/s at theta, model - experiment
    history: list[dict[str, Any]] = field(
        default_factory=list
    )  # per iteration: dict(iteration, loss, C_d, C_h, grad (d loss /
    #                                               d theta), grad_norm, residuals, evaluations, seconds)
    stopped: str = ""
    seconds: float = 0.0
    method: str = "adam"
    evaluations: int = 0  # value-and-gradient evaluations (line searches included)

    @property
    def values(self) -> np.ndarray:
        """(2,) the best (C_d, C_h) = exp(theta)."""
        return np.exp(self.theta)


def _optax_update(
    opt: optax.GradientTransformationExtraArgs, gradient: jax.Array, state: Any, theta: jax.Array, **extra: Any
) -> tuple[jax.Array, Any]:
    """(theta_new, state): optax's update and apply_updates run under JAX's standard dtype
    promotion. optax (third-party code) mixes dtypes implicitly (its step count and schedules
    against float64 parameters), which the strict promotion of jaxmpm's tests would reject; the
    promotion it gets here is the one it was written for, so its results are unchanged."""
    with jax.numpy_dtype_promotion("standard"):
        updates, state = opt.update(gradient, state, theta, **extra)
        return optax.apply_updates(theta, updates), state


def _adam_step(loss: Callable, learning_rate: float, decay: float) -> tuple[Callable, Callable]:
    """(init, step): step(theta, state) -> (theta_new, state, loss, residuals, grad, evaluations)."""
    value_and_grad = jax.value_and_grad(loss, has_aux=True)
    opt = optax.adam(optax.exponential_decay(learning_rate, transition_steps=1, decay_rate=decay))

    @jit
    def step(theta, state):
        (value, residuals), gradient = value_and_grad(theta)
        theta, state = _optax_update(opt, gradient, state, theta)
        return theta, state, value, residuals, gradient, 1

    return opt.init, step


def _lbfgs_step(loss: Callable) -> tuple[Callable, Callable]:
    """As _adam_step for optax's L-BFGS; the residuals are those of the iterate (one forward run)."""
    value_fn = lambda theta: loss(theta)[0]
    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(value_fn)

    @jit
    def step(theta, state):
        value, gradient = value_and_grad(theta, state=state)
        new_theta, new_state = _optax_update(opt, gradient, state, theta, value=value, grad=gradient, value_fn=value_fn)
        n_eval = 1 + optax.tree_utils.tree_get(new_state, "num_linesearch_steps")
        return new_theta, new_state, value, loss(theta)[1], gradient, n_eval

    return opt.init, step


def fit(
    velocities: Observables,
    target: ArrayLike,
    theta0: ArrayLike,
    iterations: int = 30,
    learning_rate: float = 0.15,
    decay: float = 0.97,
    tol: float = 1e-6,
    rtol: float = 1e-4,
    patience: int = 5,
    weights: ArrayLike | None = None,
    progress: bool = True,
    method: str = "adam",
) -> FitResult:
    """Minimise the loss over theta from theta0 with `method` ('adam' or 'lbfgs').
    velocities: theta (2,) -> (3,) km/s (or any observables), differentiable; target: of its shape.
    learning_rate > 0 and decay in (0, 1] (Adam's rate at iteration k: learning_rate * decay^k);
    weights: None (all 1) or >= 0 of target's shape. Bad arguments raise ValueError before any run."""
    check_options(iterations, learning_rate, decay, tol, rtol, patience, method)
    target, theta0, weights = check_arrays(velocities, target, theta0, weights)
    loss = loss_fn(velocities, target, weights)
    init, step = _adam_step(loss, learning_rate, decay) if method == "adam" else _lbfgs_step(loss)
    theta = jnp.asarray(theta0, jnp.zeros(()).dtype)
    # strong types throughout: a weakly typed leaf of the initial state would compile the step twice
    state = jax.tree.map(lambda x: jnp.array(x, dtype=x.dtype), init(theta))
    result = FitResult(theta=np.asarray(theta), loss=np.inf, residuals=np.full(target.shape, np.nan), method=method)
    bar = None
    if progress:
        bar = tqdm(total=iterations, desc=f"fit ({method})", unit="it")
    start = time.perf_counter()
    result.stopped = f"iterations ({iterations})"
    for iteration in range(iterations):
        t0 = time.perf_counter()
        new_theta, new_state, loss_value, residuals, gradient_array, evaluations = step(theta, state)
        loss_value, gradient, evaluations = float(loss_value), np.asarray(gradient_array), int(evaluations)
        result.evaluations += evaluations
        if not (np.isfinite(loss_value) and np.all(np.isfinite(gradient))):
            result.stopped = (
                f"non-finite loss or gradient at iteration {iteration} (theta = {np.asarray(theta).tolist()})"
            )
            break
        theta_np, residuals = np.asarray(theta), np.asarray(residuals)
        _record(result, iteration, theta_np, loss_value, gradient, residuals, evaluations, time.perf_counter() - t0)
        if bar is not None:
            entry = result.history[-1]
            bar.set_postfix_str(f"loss={loss_value:.4g} C_d={entry['C_d']:.4g} C_h={entry['C_h']:.4g}")
            bar.update(1)
        reason = _stop_reason(result.history, loss_value, tol, rtol, patience)
        if reason:
            result.stopped = reason
            break
        theta, state = new_theta, new_state
    if bar is not None:
        bar.close()
    result.seconds = time.perf_counter() - start
    return result


def _record(
    result: FitResult,
    iteration: int,
    theta: np.ndarray,
    loss: float,
    gradient: np.ndarray,
    residuals: np.ndarray,
    evaluations: int,
    seconds: float,
) -> None:
    """Append an iteration at theta (2,) to result.history (gradient (2,), residuals (3,)), and keep
    theta, its loss and residuals as the result where the loss is the lowest yet."""
    values = np.exp(theta)
    result.history.append(
        dict(
            iteration=iteration,
            loss=loss,
            C_d=float(values[0]),
            C_h=float(values[1]),
            grad=gradient.tolist(),
            grad_norm=float(np.linalg.norm(gradient)),
            residuals=residuals.tolist(),
            evaluations=evaluations,
            seconds=seconds,
        )
    )
    if loss < result.loss:
        result.theta, result.loss, result.residuals = theta, loss, residuals


def _stop_reason(history: list[dict[str, Any]], loss: float, tol: float, rtol: float, patience: int) -> str:
    """Why a fit stops after the iteration of `loss` ('' where it goes on): the loss fell below tol,
    or it changed by less than rtol relative over the last `patience` iterations of history."""
    if loss < tol:
        return f"loss {loss:.3g} < tol {tol:g}"
    losses = [entry["loss"] for entry in history]
    if len(losses) > patience and abs(losses[-1 - patience] - losses[-1]) <= rtol * losses[-1 - patience]:
        return f"loss changed by < {rtol:g} relative over {patience} iterations"
    return ""


@dataclass
class MultiStartResult:
    fits: list[FitResult]  # one FitResult per start, in the order of the starts
    best: int  # index of the start whose best iterate has the lowest loss
    seconds: float = 0.0

    @property
    def best_fit(self) -> FitResult:
        """The FitResult of the best start."""
        return self.fits[self.best]


def best_start(fits: Sequence[FitResult]) -> int:
    """Index of the fit with the lowest loss (the first of equals); non-finite losses never win
    unless all are."""
    losses = np.array([f.loss if np.isfinite(f.loss) else np.inf for f in fits])
    return int(np.argmin(losses))


def fit_starts(
    velocities: Observables,
    target: ArrayLike,
    theta0s: ArrayLike,
    iterations: int = 30,
    learning_rate: float = 0.15,
    decay: float = 0.97,
    tol: float = 1e-6,
    rtol: float = 1e-4,
    patience: int = 5,
    weights: ArrayLike | None = None,
    progress: bool = True,
) -> MultiStartResult:
    """Adam from each of K starting points theta0s (K, 2), all K advanced together: every
    iteration is one vmapped value-and-gradient of the K points (`jax.vmap` of `fit`'s Adam step),
    so a batch costs one compiled program. Each start stops by `fit`'s rules (loss < tol, or a
    relative change < rtol over patience iterations, or a non-finite loss or gradient); a stopped
    start's theta is then held while the others go on. Returns a MultiStartResult: a FitResult per
    start (its best iterate and history, as `fit` would give it alone) and the index of the best.
    Bad arguments raise ValueError before any run."""
    # longer than 60 lines on purpose: one optimiser loop over the vmapped starts with their stopping tests and
    # history
    check_options(iterations, learning_rate, decay, tol, rtol, patience, "adam")
    starts = check_starts(theta0s)
    target, _, weights = check_arrays(velocities, target, starts[0], weights)
    loss = loss_fn(velocities, target, weights)
    init, step = _adam_step(loss, learning_rate, decay)
    batched_step = jit(jax.vmap(step))
    n_starts = starts.shape[0]
    theta = jnp.asarray(starts, jnp.zeros(()).dtype)
    state = jax.tree.map(lambda x: jnp.array(x, dtype=x.dtype), jax.vmap(init)(theta))
    fits = [
        FitResult(theta=starts[k], loss=np.inf, residuals=np.full(target.shape, np.nan), method="adam")
        for k in range(n_starts)
    ]
    for result in fits:
        result.stopped = f"iterations ({iterations})"
    active = np.ones(n_starts, bool)
    bar = None
    if progress:
        bar = tqdm(total=iterations, desc=f"fit (adam, {n_starts} starts)", unit="it")
    start = time.perf_counter()
    for iteration in range(iterations):
        t0 = time.perf_counter()
        new_theta, new_state, loss_value, residuals, gradient, _ = batched_step(theta, state)
        loss_value, residuals, gradient = np.asarray(loss_value), np.asarray(residuals), np.asarray(gradient)
        seconds = time.perf_counter() - t0
        thetas = np.asarray(theta)
        for k in np.flatnonzero(active):
            result = fits[k]
            result.evaluations += 1
            if not (np.isfinite(loss_value[k]) and np.all(np.isfinite(gradient[k]))):
                result.stopped = f"non-finite loss or gradient at iteration {iteration} (theta = {thetas[k].tolist()})"
                active[k] = False
                continue
            value = float(loss_value[k])
            _record(result, iteration, thetas[k].copy(), value, gradient[k], residuals[k].copy(), 1, seconds)
            reason = _stop_reason(result.history, value, tol, rtol, patience)
            if reason:
                result.stopped = reason
                active[k] = False
        if bar is not None:
            best = best_start(fits)
            bar.set_postfix_str(f"best loss={fits[best].loss:.4g} (start {best}), {int(active.sum())} active")
            bar.update(1)
        if not active.any():
            break
        keep = jnp.asarray(active)
        hold = lambda new, old: jnp.where(keep.reshape((n_starts,) + (1,) * (new.ndim - 1)), new, old)
        theta = hold(new_theta, theta)
        state = jax.tree.map(hold, new_state, state)
    if bar is not None:
        bar.close()
    seconds = time.perf_counter() - start
    for result in fits:
        result.seconds = seconds
    return MultiStartResult(fits=fits, best=best_start(fits), seconds=seconds)


def spread_starts(first: Sequence[float], k: int, c_d_range: Sequence[float], c_h_range: Sequence[float]) -> np.ndarray:
    """k starting points (k, 2) of theta = (log C_d, log C_h): `first` (C_d, C_h), then k - 1 points
    of the Halton sequence (bases 2 and 3, unscrambled: the same points every run) over the
    log-spaced box c_d_range x c_h_range."""
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"starts = {k!r} is invalid: allowed an integer >= 1")

    def halton(i: int, base: int) -> float:
        f, x = 1.0, 0.0
        while i > 0:
            f /= base
            x += f * (i % base)
            i //= base
        return x

    lo = np.log([c_d_range[0], c_h_range[0]])
    hi = np.log([c_d_range[1], c_h_range[1]])
    pts = [np.log(np.asarray(first, float))]
    pts += [lo + (hi - lo) * np.array([halton(i, 2), halton(i, 3)]) for i in range(1, k)]
    return np.stack(pts)


def standard_errors(
    velocities: Observables, theta: ArrayLike, residuals: ArrayLike, weights: ArrayLike | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Gauss-Newton standard errors of theta (2,) and of (C_d, C_h) (2,), the Jacobian J (3, 2) and
    the condition number of J^T W J, at theta (2,) with residuals (3,) and weights (3,) (None: 1)."""
    J = np.asarray(jax.jacfwd(velocities)(jnp.asarray(theta)))
    r = np.asarray(residuals)
    w = np.ones_like(r) if weights is None else np.asarray(weights, float)
    n, p = J.shape
    s2 = float(np.sum(w * r * r)) / max(n - p, 1)
    JtJ = J.T @ (w[:, None] * J)
    cov = s2 * np.linalg.pinv(JtJ)
    se_theta = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return se_theta, np.exp(np.asarray(theta)) * se_theta, J, float(np.linalg.cond(JtJ))


def landscape(
    velocities_batch: Callable[[np.ndarray], ArrayLike],
    target: ArrayLike,
    c_d_values: ArrayLike,
    c_h_values: ArrayLike,
    weights: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Loss (len(c_h), len(c_d)) over the grid, and the velocities (len(c_h), len(c_d), 3), every
    point in one vmapped call of velocities_batch: thetas (B, 2) -> (B, 3) km/s."""
    c_d_grid, c_h_grid = np.meshgrid(np.asarray(c_d_values, float), np.asarray(c_h_values, float))
    thetas = np.log(np.stack([c_d_grid.ravel(), c_h_grid.ravel()], -1))
    velocities = np.asarray(velocities_batch(thetas))
    weight = np.ones(3) if weights is None else np.asarray(weights, float)
    loss = np.sum(weight * (velocities - np.asarray(target)) ** 2, -1)
    return loss.reshape(c_d_grid.shape), velocities.reshape(c_d_grid.shape + (3,))
