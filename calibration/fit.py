"""Gradient-descent fit of (C_d, C_h) to the measured feature velocities, its standard errors,
and the loss landscape.

Loss (km/s)^2: L(theta) = sum_i w_i (v_i(theta) - v_i^exp)^2 over points 1, 2, 4, with
theta = (log C_d, log C_h) and weights w (default 1). Optimiser: optax Adam with an exponentially
decaying learning rate; stops early when the loss falls below `tol` or changes by less than
`rtol` relative over `patience` iterations. The best iterate is returned (not the last).

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
    theta: np.ndarray                        # (2,) best (log C_d, log C_h)
    loss: float                              # at theta, (km/s)^2
    residuals: np.ndarray                    # (3,) km/s at theta, model - experiment
    history: list = field(default_factory=list)   # per iteration: dict(iteration, loss, C_d, C_h, grad_norm, seconds)
    stopped: str = ""
    seconds: float = 0.0

    @property
    def values(self):
        return np.exp(self.theta)


def fit(velocities, target, theta0, iterations=30, learning_rate=0.15, decay=0.97, tol=1e-6, rtol=1e-4,
        patience=5, weights=None, progress=True):
    """Adam on theta from theta0. velocities: theta (2,) -> (3,) km/s, differentiable."""
    if not (isinstance(iterations, int) and iterations >= 1):
        raise ValueError(f"iterations = {iterations!r} is invalid: allowed an integer >= 1")
    value_and_grad = jax.jit(jax.value_and_grad(loss_fn(velocities, target, weights), has_aux=True))
    schedule = optax.exponential_decay(learning_rate, transition_steps=1, decay_rate=decay)
    opt = optax.adam(schedule)
    theta = jnp.asarray(theta0, jnp.zeros(()).dtype)
    state = opt.init(theta)
    result = FitResult(theta=np.asarray(theta), loss=np.inf, residuals=np.full(3, np.nan))
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=iterations, desc="fit", unit="it")
    start = time.perf_counter()
    result.stopped = f"iterations ({iterations})"
    for it in range(iterations):
        t0 = time.perf_counter()
        (loss, r), g = value_and_grad(theta)
        loss, g_np = float(loss), np.asarray(g)
        if not (np.isfinite(loss) and np.all(np.isfinite(g_np))):
            result.stopped = f"non-finite loss or gradient at iteration {it} (theta = {np.asarray(theta).tolist()})"
            break
        c = np.exp(np.asarray(theta))
        result.history.append(dict(iteration=it, loss=loss, C_d=float(c[0]), C_h=float(c[1]),
                                   grad_norm=float(np.linalg.norm(g_np)), residuals=np.asarray(r).tolist(),
                                   seconds=time.perf_counter() - t0))
        if loss < result.loss:
            result.theta, result.loss, result.residuals = np.asarray(theta), loss, np.asarray(r)
        if bar is not None:
            bar.set_postfix_str(f"loss={loss:.4g} C_d={c[0]:.4g} C_h={c[1]:.4g}")
            bar.update(1)
        if loss < tol:
            result.stopped = f"loss {loss:.3g} < tol {tol:g}"
            break
        losses = [h["loss"] for h in result.history]
        if len(losses) > patience and abs(losses[-1 - patience] - losses[-1]) <= rtol * losses[-1 - patience]:
            result.stopped = f"loss changed by < {rtol:g} relative over {patience} iterations"
            break
        updates, state = opt.update(g, state, theta)
        theta = optax.apply_updates(theta, updates)
    if bar is not None:
        bar.close()
    result.seconds = time.perf_counter() - start
    return result


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
