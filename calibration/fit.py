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
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

from jaxmpm.numerics.compile import jit


def loss_fn(velocities, target, weights=None):
    """theta -> weighted sum of squared residuals (km/s)^2, and the residuals (3,)."""
    target = jnp.asarray(target)
    w = jnp.ones_like(target) if weights is None else jnp.asarray(weights, target.dtype)

    def loss(theta):
        r = velocities(theta) - target
        return jnp.sum(w * r * r), r

    return loss


@dataclass
class FitResult:
    theta: np.ndarray  # (2,) best (log C_d, log C_h)
    loss: float  # at theta, (km/s)^2
    residuals: np.ndarray  # (3,) km/s at theta, model - experiment
    history: list = field(default_factory=list)  # per iteration: dict(iteration, loss, C_d, C_h, grad (d loss /
    #                                               d theta), grad_norm, residuals, evaluations, seconds)
    stopped: str = ""
    seconds: float = 0.0
    method: str = "adam"
    evaluations: int = 0  # value-and-gradient evaluations (line searches included)

    @property
    def values(self):
        return np.exp(self.theta)


METHODS = ("adam", "lbfgs")


def _optax_update(opt, gradient, state, theta, **extra):
    """(theta_new, state): optax's update and apply_updates run under JAX's standard dtype
    promotion. optax (third-party code) mixes dtypes implicitly (its step count and schedules
    against float64 parameters), which the strict promotion of jaxmpm's tests would reject; the
    promotion it gets here is the one it was written for, so its results are unchanged."""
    with jax.numpy_dtype_promotion("standard"):
        updates, state = opt.update(gradient, state, theta, **extra)
        return optax.apply_updates(theta, updates), state


def _adam_step(loss, learning_rate, decay):
    """(init, step): step(theta, state) -> (theta_new, state, loss, residuals, grad, evaluations)."""
    value_and_grad = jax.value_and_grad(loss, has_aux=True)
    opt = optax.adam(optax.exponential_decay(learning_rate, transition_steps=1, decay_rate=decay))

    @jit
    def step(theta, state):
        (value, r), g = value_and_grad(theta)
        theta, state = _optax_update(opt, g, state, theta)
        return theta, state, value, r, g, 1

    return opt.init, step


def _lbfgs_step(loss):
    """As _adam_step for optax's L-BFGS; the residuals are those of the iterate (one forward run)."""
    value_fn = lambda th: loss(th)[0]
    opt = optax.lbfgs()
    value_and_grad = optax.value_and_grad_from_state(value_fn)

    @jit
    def step(theta, state):
        value, g = value_and_grad(theta, state=state)
        new_theta, new_state = _optax_update(opt, g, state, theta, value=value, grad=g, value_fn=value_fn)
        n_eval = 1 + optax.tree_utils.tree_get(new_state, "num_linesearch_steps")
        return new_theta, new_state, value, loss(theta)[1], g, n_eval

    return opt.init, step


def _real(value):
    """value as a float; nan where it is not a real number (a string, an array of several)."""
    if isinstance(value, (str, bytes)):
        return np.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return np.nan


def _float_array(value):
    """value as a float array; None where it is not numeric."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None


def _require(ok, name, value, allowed):
    if not ok:
        raise ValueError(f"{name} = {value!r} is invalid: allowed {allowed}")


def check_options(iterations, learning_rate, decay, tol, rtol, patience, method):
    """Refuse out-of-range scalar options of `fit` (ValueError naming the option and its range)."""
    integer = lambda x: isinstance(x, (int, np.integer)) and not isinstance(x, bool)
    _require(integer(iterations) and iterations >= 1, "iterations", iterations, "an integer >= 1")
    _require(method in METHODS, "method", method, " | ".join(METHODS))
    lr, d, t, rt = _real(learning_rate), _real(decay), _real(tol), _real(rtol)
    _require(
        np.isfinite(lr) and lr > 0, "learning_rate", learning_rate, "a finite number > 0 (Adam's step in log space)"
    )
    _require(0 < d <= 1, "decay", decay, "a number in (0, 1] (the learning rate's factor per iteration; 1: constant)")
    _require(np.isfinite(t) and t >= 0, "tol", tol, "a finite number >= 0 (km/s)^2")
    _require(np.isfinite(rt) and rt >= 0, "rtol", rtol, "a finite number >= 0")
    _require(integer(patience) and patience >= 1, "patience", patience, "an integer >= 1")


def check_arrays(velocities, target, theta0, weights):
    """(target, theta0, weights) as float arrays, checked: theta0 finite (2,); target finite, of the
    shape of velocities(theta0) (found by tracing, without running it); weights None or finite,
    >= 0, not all 0, of target's shape. ValueError naming the argument otherwise."""
    th = _float_array(theta0)
    _require(
        th is not None and th.shape == (2,) and np.all(np.isfinite(th)),
        "theta0",
        theta0,
        "finite numbers of shape (2,): (log C_d, log C_h)",
    )
    tg = _float_array(target)
    _require(tg is not None and np.all(np.isfinite(tg)), "target", target, "finite numbers (km/s)")
    shape = jax.eval_shape(velocities, jnp.asarray(th, jnp.zeros(()).dtype)).shape
    if tg.shape != shape:
        raise ValueError(f"target of shape {tg.shape} is invalid: allowed the shape of velocities(theta0), {shape}")
    if weights is None:
        return tg, th, None
    w = _float_array(weights)
    _require(
        w is not None and w.shape == tg.shape and np.all(np.isfinite(w) & (w >= 0)) and np.any(w > 0),
        "weights",
        weights,
        f"None or finite numbers >= 0, not all 0, of target's shape {tg.shape}",
    )
    return tg, th, w


def fit(
    velocities,
    target,
    theta0,
    iterations=30,
    learning_rate=0.15,
    decay=0.97,
    tol=1e-6,
    rtol=1e-4,
    patience=5,
    weights=None,
    progress=True,
    method="adam",
):
    """Minimise the loss over theta from theta0 with `method` ('adam' or 'lbfgs').
    velocities: theta (2,) -> (3,) km/s (or any observables), differentiable; target: of its shape.
    learning_rate > 0 and decay in (0, 1] (Adam's rate at iteration k: learning_rate * decay^k);
    weights: None (all 1) or >= 0 of target's shape. Bad arguments raise ValueError before any run."""
    # longer than 60 lines on purpose: one optimiser loop (Adam or L-BFGS) with its stopping tests and history
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
    for it in range(iterations):
        t0 = time.perf_counter()
        new_theta, new_state, loss_v, r, g, n_eval = step(theta, state)
        loss_v, g_np, n_eval = float(loss_v), np.asarray(g), int(n_eval)
        result.evaluations += n_eval
        if not (np.isfinite(loss_v) and np.all(np.isfinite(g_np))):
            result.stopped = f"non-finite loss or gradient at iteration {it} (theta = {np.asarray(theta).tolist()})"
            break
        c = np.exp(np.asarray(theta))
        result.history.append(
            dict(
                iteration=it,
                loss=loss_v,
                C_d=float(c[0]),
                C_h=float(c[1]),
                grad=g_np.tolist(),
                grad_norm=float(np.linalg.norm(g_np)),
                residuals=np.asarray(r).tolist(),
                evaluations=n_eval,
                seconds=time.perf_counter() - t0,
            )
        )
        if loss_v < result.loss:
            result.theta, result.loss, result.residuals = np.asarray(theta), loss_v, np.asarray(r)
        if bar is not None:
            bar.set_postfix_str(f"loss={loss_v:.4g} C_d={c[0]:.4g} C_h={c[1]:.4g}")
            bar.update(1)
        if loss_v < tol:
            result.stopped = f"loss {loss_v:.3g} < tol {tol:g}"
            break
        losses = [h["loss"] for h in result.history]
        if len(losses) > patience and abs(losses[-1 - patience] - losses[-1]) <= rtol * losses[-1 - patience]:
            result.stopped = f"loss changed by < {rtol:g} relative over {patience} iterations"
            break
        theta, state = new_theta, new_state
    if bar is not None:
        bar.close()
    result.seconds = time.perf_counter() - start
    return result


def check_starts(theta0s):
    """theta0s as a float array (K, 2) of finite starting points, K >= 1; ValueError otherwise."""
    th = _float_array(theta0s)
    _require(
        th is not None and th.ndim == 2 and th.shape[0] >= 1 and th.shape[1] == 2 and np.all(np.isfinite(th)),
        "theta0s",
        theta0s,
        "finite numbers of shape (K, 2), K >= 1: K starting points (log C_d, log C_h)",
    )
    return th


@dataclass
class MultiStartResult:
    fits: list  # one FitResult per start, in the order of the starts
    best: int  # index of the start whose best iterate has the lowest loss
    seconds: float = 0.0

    @property
    def best_fit(self):
        return self.fits[self.best]


def best_start(fits):
    """Index of the fit with the lowest loss (the first of equals); non-finite losses never win
    unless all are."""
    losses = np.array([f.loss if np.isfinite(f.loss) else np.inf for f in fits])
    return int(np.argmin(losses))


def fit_starts(
    velocities,
    target,
    theta0s,
    iterations=30,
    learning_rate=0.15,
    decay=0.97,
    tol=1e-6,
    rtol=1e-4,
    patience=5,
    weights=None,
    progress=True,
):
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
    vstep = jit(jax.vmap(step))
    K = starts.shape[0]
    theta = jnp.asarray(starts, jnp.zeros(()).dtype)
    state = jax.tree.map(lambda x: jnp.array(x, dtype=x.dtype), jax.vmap(init)(theta))
    fits = [
        FitResult(theta=starts[k], loss=np.inf, residuals=np.full(target.shape, np.nan), method="adam")
        for k in range(K)
    ]
    for f in fits:
        f.stopped = f"iterations ({iterations})"
    active = np.ones(K, bool)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=iterations, desc=f"fit (adam, {K} starts)", unit="it")
    start = time.perf_counter()
    for it in range(iterations):
        t0 = time.perf_counter()
        new_theta, new_state, loss_v, r, g, _ = vstep(theta, state)
        loss_v, r, g = np.asarray(loss_v), np.asarray(r), np.asarray(g)
        seconds = time.perf_counter() - t0
        th_np = np.asarray(theta)
        for k in np.flatnonzero(active):
            f = fits[k]
            f.evaluations += 1
            if not (np.isfinite(loss_v[k]) and np.all(np.isfinite(g[k]))):
                f.stopped = f"non-finite loss or gradient at iteration {it} (theta = {th_np[k].tolist()})"
                active[k] = False
                continue
            c = np.exp(th_np[k])
            f.history.append(
                dict(
                    iteration=it,
                    loss=float(loss_v[k]),
                    C_d=float(c[0]),
                    C_h=float(c[1]),
                    grad=g[k].tolist(),
                    grad_norm=float(np.linalg.norm(g[k])),
                    residuals=r[k].tolist(),
                    evaluations=1,
                    seconds=seconds,
                )
            )
            if loss_v[k] < f.loss:
                f.theta, f.loss, f.residuals = th_np[k].copy(), float(loss_v[k]), r[k].copy()
            if loss_v[k] < tol:
                f.stopped = f"loss {loss_v[k]:.3g} < tol {tol:g}"
                active[k] = False
                continue
            losses = [h["loss"] for h in f.history]
            if len(losses) > patience and abs(losses[-1 - patience] - losses[-1]) <= rtol * losses[-1 - patience]:
                f.stopped = f"loss changed by < {rtol:g} relative over {patience} iterations"
                active[k] = False
        if bar is not None:
            b = best_start(fits)
            bar.set_postfix_str(f"best loss={fits[b].loss:.4g} (start {b}), {int(active.sum())} active")
            bar.update(1)
        if not active.any():
            break
        keep = jnp.asarray(active)
        hold = lambda new, old: jnp.where(keep.reshape((K,) + (1,) * (new.ndim - 1)), new, old)
        theta = hold(new_theta, theta)
        state = jax.tree.map(hold, new_state, state)
    if bar is not None:
        bar.close()
    seconds = time.perf_counter() - start
    for f in fits:
        f.seconds = seconds
    return MultiStartResult(fits=fits, best=best_start(fits), seconds=seconds)


def spread_starts(first, k, c_d_range, c_h_range):
    """k starting points (k, 2) of theta = (log C_d, log C_h): `first` (C_d, C_h), then k - 1 points
    of the Halton sequence (bases 2 and 3, unscrambled: the same points every run) over the
    log-spaced box c_d_range x c_h_range."""
    if not (isinstance(k, (int, np.integer)) and k >= 1):
        raise ValueError(f"starts = {k!r} is invalid: allowed an integer >= 1")

    def halton(i, base):
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


def standard_errors(velocities, theta, residuals, weights=None):
    """Gauss-Newton standard errors of theta (2,) and of (C_d, C_h) (2,), and the Jacobian (3, 2)."""
    J = np.asarray(jax.jacfwd(velocities)(jnp.asarray(theta)))
    r = np.asarray(residuals)
    w = np.ones_like(r) if weights is None else np.asarray(weights, float)
    n, p = J.shape
    s2 = float(np.sum(w * r * r)) / max(n - p, 1)
    JtJ = J.T @ (w[:, None] * J)
    cov = s2 * np.linalg.pinv(JtJ)
    se_theta = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return se_theta, np.exp(np.asarray(theta)) * se_theta, J, float(np.linalg.cond(JtJ))


def landscape(velocities_batch, target, c_d_values, c_h_values, weights=None):
    """Loss (len(c_h), len(c_d)) over the grid, every point in one vmapped call."""
    cd, ch = np.meshgrid(np.asarray(c_d_values, float), np.asarray(c_h_values, float))
    thetas = np.log(np.stack([cd.ravel(), ch.ravel()], -1))
    v = np.asarray(velocities_batch(thetas))
    w = np.ones(3) if weights is None else np.asarray(weights, float)
    loss = np.sum(w * (v - np.asarray(target)) ** 2, -1)
    return loss.reshape(cd.shape), v.reshape(cd.shape + (3,))
