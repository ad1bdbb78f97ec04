"""jaxmpm.jit's compiler options and the two forms of the contractions (compile.py)."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import jaxmpm
from jaxmpm.numerics.compile import native_reductions, native_reductions_forms


def _form_value(x):
    return x * (2.0 if native_reductions() else 3.0)


@pytest.mark.skipif(
    not jaxmpm.numerics.compile._USER_CONTEXTS,
    reason="a jax without user contexts: jit compiles with XLA's defaults and traces no reduction form",
)
def test_caches_of_traces_tell_the_two_forms_apart():
    """A trace made in one form is never reused in the other: not by one jax.jit, nor by the
    caches JAX keys on the traced function (jax.checkpoint's), nor by jaxmpm.jit's staged call."""
    one_jit = jax.jit(_form_value)
    checkpointed = jax.checkpoint(_form_value)
    staged = jaxmpm.jit(_form_value)
    for on, factor in ((True, 2.0), (False, 3.0), (True, 2.0)):
        with native_reductions_forms(on):
            assert float(one_jit(1.0)) == factor
            assert float(jax.jit(lambda x: checkpointed(x))(1.0)) == factor
    # staged by an eager grad (plain forms) after a trace inside jaxmpm.jit (reductions)
    assert float(jaxmpm.jit(jax.grad(lambda x: staged(x)))(1.0)) == (
        2.0 if jaxmpm.numerics.compile.compiler_options() else 3.0
    )
    assert float(jax.grad(lambda x: staged(x))(1.0)) == 3.0


README_GRADIENT = textwrap.dedent("""
    import sys, jax, jaxmpm
    from jaxmpm import Scene, Grid, Phase, Box, Sphere, Material
    rubber = Material.make("rubber", "hypoelastic", rho0=1100.0, E=2.0e5, nu=0.3)
    stiff = Material.make("stiff", "hypoelastic", rho0=7800.0, E=2.0e7, nu=0.3)
    scene = Scene(grid=Grid(cells=(16, 16), h=1 / 16), materials=(rubber, stiff),
                  phases=(Phase("ball", "rubber", Sphere((0.5, 0.5), 0.2), velocity=(0.0, -3.0)),
                          Phase("block", "stiff", Box((0.2, 0.0), (0.8, 0.3)))),
                  boundary=jaxmpm.Boundary(faces=(("y_lo", "fixed"),)), gravity=(0.0, -9.81), t_end=0.01)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    assert state.x.dtype == "float32"
    n = jaxmpm.plan_steps(scene, params, state, scene.t_end)
    height = lambda E: jaxmpm.simulate(scene, params.with_constant("ball", "E", E), state,
                                       n_steps=n)[0].x[:, 1].mean()
    for order in sys.argv[1]:
        g = jaxmpm.jit(jax.grad(height))(2.0e5) if order == "j" else jax.grad(height)(2.0e5)
        print(order, repr(float(g)), flush=True)
""")


def _gradients(order):
    env = {k: v for k, v in os.environ.items() if k != "JAXMPM_XLA_DEFAULTS"}
    r = subprocess.run(
        [sys.executable, "-c", README_GRADIENT, order], capture_output=True, text=True, timeout=600, env=env
    )
    assert r.returncode == 0, f"order {order!r}: exit status {r.returncode}\n{r.stderr[-3000:]}"
    return dict(line.split() for line in r.stdout.splitlines())


@pytest.mark.slow
def test_readme_gradient_compiled_and_eager_in_either_order():
    """The README's gradient example (float32, at a small size where the ball presses the block):
    jaxmpm.jit(jax.grad(height)) and an eager jax.grad(height) in one process, in both orders,
    exit 0 with the same gradients (the eager grad after the compiled one used to crash in
    YNNPACK, which took the reductions traced for jaxmpm.jit)."""
    first, second = _gradients("je"), _gradients("ej")
    assert first == second  # each form's gradient does not depend on the order
    g_jit, g_eager = float(first["j"]), float(first["e"])
    assert abs(g_jit) > 1e-10
    # the two forms round differently in float32 (reductions against unrolled sums): a few ulps
    np.testing.assert_allclose(g_eager, g_jit, rtol=1e-5)
