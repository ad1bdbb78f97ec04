"""Multi-velocity multiphase: implicit exchange (E3), interface forces (E13), remap exchange (E14)."""
import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.scene import Box, Grid, Phase, Scene

HEAVY = jaxmpm.Material.make("heavy", "linear_fluid", rho0=1000.0, K=1000.0)
LIGHT = jaxmpm.Material.make("light", "linear_fluid", rho0=1.0, K=1.0)


def mixture(drag=None, linear_drag=None, dv0=1e-3, cells=10):
    """Two phases filling the same 1D box, half the volume each, light phase moving at dv0."""
    box = Box((0.0,), (1.0,))
    return Scene(grid=Grid(cells=(cells,), h=1.0 / cells), materials=(HEAVY, LIGHT),
                 phases=(Phase("heavy", "heavy", box, field=0, fraction=0.5),
                         Phase("light", "light", box, field=1, fraction=0.5, velocity=(dv0,))),
                 drag=drag, linear_drag=linear_drag, t_end=1.0, n_out=5)


def rate_constants(scene, params):
    """k of d(dv)/dt = -k |dv| dv (quadratic) or -lam dv (linear), from (E3) at theta = 1/2."""
    th, rA, rB = 0.5, 1000.0, 1.0
    inv = 1 / (rA * th) + 1 / (rB * th)
    k = float(params.drag_coefficient) * th * th * rB / float(params.drag_length) * inv
    lam = float(params.linear_drag) * th * th * inv
    return k, lam


def relative_velocity(scene, state):
    sl = jaxmpm.state.phase_slices(scene)
    return np.asarray(jnp.mean(state.v[sl[1], 0]) - jnp.mean(state.v[sl[0], 0]))


def run_relaxation(scene, dt):
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    final, hist = jaxmpm.simulate(scene, params, s0, dt=dt, progress=False)
    dv = np.array([relative_velocity(scene, jax.tree.map(lambda a: a[i], hist)) for i in range(len(hist.t))])
    p0, p1 = np.asarray(jaxmpm.diagnostics.momentum(s0)), np.asarray(jaxmpm.diagnostics.momentum(final))
    return params, np.asarray(hist.t), dv, p0, p1, hist


@pytest.mark.parametrize("kind", ["quadratic", "linear"])
def test_drag_relaxation_matches_exact_first_order_momentum_exact(kind):
    scene = mixture(drag=1000.0) if kind == "quadratic" else mixture(linear_drag=4.0)
    errs = []
    for dt in (0.02, 0.01, 0.005):
        params, t, dv, p0, p1, hist = run_relaxation(scene, dt)
        k, lam = rate_constants(scene, params)
        dv0 = 1e-3
        exact = dv0 / (1 + k * dv0 * t) if kind == "quadratic" else dv0 * np.exp(-lam * t)
        errs.append(np.max(np.abs(dv - exact)) / dv0)
        np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-12 * abs(p0).max())
        # uniform up to the edge nodes, where the particles' shift (1% of a cell) changes theta
        for sl in jaxmpm.state.phase_slices(scene):
            assert float(jnp.std(hist.v[-1, sl, 0])) < 1e-3 * dv0
    assert exact[-1] < 0.3 * dv0                       # it relaxed substantially
    print(f"{kind} drag: max relative errors at dt = 0.02, 0.01, 0.005 s: {errs}")
    if kind == "quadratic":
        # the linearised implicit step dv' = dv / (1 + k dt dv) is the exact flow map of
        # d(dv)/dt = -k dv^2: exact at every dt up to the particles' drift across the cells
        assert max(errs) < 1e-5
    else:
        orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
        assert np.all(orders > 0.9) and errs[-1] < 0.05


def test_stiff_drag_is_stable_without_overshoot():
    scene = mixture(drag=1e9)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    dt = 0.02
    k, _ = rate_constants(scene, params)
    assert dt * k * 1e-3 > 1e3          # dt K / m = dt k |dv| >> 1
    final, hist = jaxmpm.simulate(scene, params, s0, dt=dt, progress=False)
    dv = np.array([relative_velocity(scene, jax.tree.map(lambda a: a[i], hist)) for i in range(len(hist.t))])
    assert np.all(dv >= 0) and np.all(np.isfinite(dv))
    assert dv[-1] < 1e-5 * dv[0]
    p0, p1 = np.asarray(jaxmpm.diagnostics.momentum(s0)), np.asarray(jaxmpm.diagnostics.momentum(final))
    np.testing.assert_allclose(p1, p0, rtol=0, atol=1e-12 * abs(p0).max())
