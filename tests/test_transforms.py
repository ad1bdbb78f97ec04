"""jit, vmap and grad through the step and through simulate."""

import dataclasses
import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm


@pytest.fixture(scope="module")
def small():
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25)
    scene = dataclasses.replace(scene, t_end=1.5, n_out=3)  # the disks meet at about 1.1 s
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    return scene, params, state


def assert_same_step(scene, params, state, a, b):
    """Two results a, b of one step from `state` agree to round-off. The disks move rigidly at
    first, so their stress is round-off itself (1e-15 Pa, from L = sum v_n (x) grad S_n
    cancelling): it is compared on the scale of the stress one step can make, E |v| dt / h, not on
    its own; the internal energy (J/kg) on sigma^2 / (E rho)."""
    E = max(float(params.phases[p.name]["E"]) for p in scene.phases)
    stress_scale = E * float(jnp.abs(state.v).max()) * float(a.t - state.t) / scene.grid.h
    for name in ("x", "v", "mass", "volume", "F", "stress", "energy", "t"):
        x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
        rho = float(jnp.min(state.mass / state.volume))
        scale = {"stress": stress_scale, "energy": stress_scale**2 / (E * rho)}.get(name, float(np.abs(y).max()))
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-13 * scale, err_msg=name)
    assert float(a.t) > 0 and stress_scale > 0


@pytest.mark.slow
def test_step_under_jit_equals_eager(small):
    scene, params, state = small
    step = jaxmpm.make_step(scene)
    assert_same_step(scene, params, state, jax.jit(step)(params, state), step(params, state))


def test_vmap_over_youngs_modulus_equals_single_runs(small):
    scene, params, state = small
    n = jaxmpm.plan_steps(scene, params, state, scene.t_end)
    Es = jnp.array([500.0, 1000.0, 2000.0, 4000.0])

    def run(E):
        p = params.with_constant("disk_a", "E", E).with_constant("disk_b", "E", E)
        # the stiffer members' CFL steps are shorter: they end before t_end in n steps, batched or not
        return jaxmpm.simulate(scene, p, state, n_steps=n, allow_short=True)[0]

    batch = jax.jit(jax.vmap(run))(Es)
    for i, E in enumerate(Es):
        single = run(E)
        np.testing.assert_allclose(np.asarray(batch.x[i]), np.asarray(single.x), rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(batch.stress[i]), np.asarray(single.stress), rtol=1e-10, atol=1e-10)
    assert not np.allclose(np.asarray(batch.stress[0]), np.asarray(batch.stress[3]))


def _loss_fn(scene, params, state, n):
    def loss(E, v0):
        p = params.with_constant("disk_a", "E", E).with_constant("disk_b", "E", E)
        s = dataclasses.replace(state, v=state.v.at[: state.n_particles // 2].set(v0))
        final = jaxmpm.simulate(scene, p, s, n_steps=n, checkpoint=True)[0]
        return jnp.sum(final.mass * final.x[:, 0] * final.x[:, 1]) + jnp.sum(final.stress[:, 0, 0]) * 1e-3

    return loss


def test_grad_matches_central_differences(small):
    scene, params, state = small
    n = jaxmpm.plan_steps(scene, params, state, scene.t_end)
    loss = jax.jit(_loss_fn(scene, params, state, n))
    # v0 differs from disk_b's speed: a tie in the CFL max between the two disks would be a kink
    E0, v0 = jnp.asarray(1000.0), jnp.asarray([0.12, 0.09])
    gE, gv = jax.grad(loss, argnums=(0, 1))(E0, v0)
    # the loss is piecewise smooth (the CFL max over particles, the cell each particle occupies):
    # the difference steps stay inside one smooth piece (larger steps cross a kink)
    hE = 1e-6 * E0
    fdE = (loss(E0 + hE, v0) - loss(E0 - hE, v0)) / (2 * hE)
    np.testing.assert_allclose(float(gE), float(fdE), rtol=1e-5)
    for k in range(2):
        dv = jnp.zeros(2).at[k].set(1e-8)
        fdv = (loss(E0, v0 + dv) - loss(E0, v0 - dv)) / 2e-8
        np.testing.assert_allclose(float(gv[k]), float(fdv), rtol=1e-5)
    assert abs(float(gE)) > 0 and np.all(np.abs(np.asarray(gv)) > 0)


def test_simulate_requires_n_steps_under_transformations(small):
    scene, params, state = small
    with pytest.raises(ValueError, match="n_steps is required"):
        jax.grad(lambda E: jaxmpm.simulate(scene, params.with_constant("disk_a", "E", E), state)[0].x.sum())(1000.0)


def test_host_driver_equals_fixed_scan(small):
    scene, params, state = small
    a, ha = jaxmpm.simulate(scene, params, state, progress=False)
    n = jaxmpm.plan_steps(scene, params, state, scene.t_end)
    b, hb = jaxmpm.simulate(scene, params, state, n_steps=n)
    np.testing.assert_allclose(np.asarray(a.x), np.asarray(b.x), rtol=0, atol=1e-12)
    assert ha.x.shape == hb.x.shape == (scene.n_out + 1,) + state.x.shape
    np.testing.assert_allclose(np.asarray(ha.t), [0.0, 0.5, 1.0, 1.5], rtol=1e-12)


def _checkpointed_loss(small, checkpoint):
    """E -> (a loss of the final state and of an output, the final time) for the small scene with
    both disks' E set, 14 steps in 2 outputs."""
    scene, params, state = small

    def run(E):
        p = params.with_constant("disk_a", "E", E).with_constant("disk_b", "E", E)
        final, hist = jaxmpm.simulate(scene, p, state, t_end=1.5, n_out=2, n_steps=14, checkpoint=checkpoint)
        return jnp.sum(final.mass * final.x[:, 0] * final.x[:, 1]) + jnp.sum(hist.stress[1, :, 0, 0]) * 1e-3, final.t

    return run


@pytest.fixture(scope="module")
def plain_scan_gradient(small):
    """((loss, final time), d loss / dE) of the plain scan, the reference of every mode below."""
    return jax.value_and_grad(_checkpointed_loss(small, False), has_aux=True)(1000.0)


# True and "auto" run the programs of "nested" and "steps" (checkpoint_mode: the test below), so
# they are in the slow set
@pytest.mark.parametrize(
    "mode",
    [
        pytest.param(True, marks=pytest.mark.slow),
        pytest.param("nested", marks=pytest.mark.slow),
        "steps",
        pytest.param("auto", marks=pytest.mark.slow),
    ],
)
def test_checkpointing_gives_the_same_run_and_gradient(small, plain_scan_gradient, mode):
    """checkpoint=True / "nested" (two-level checkpointing; 7 steps per output run as 3 chunks of 3,
    the last two steps padding), "steps" (each step recomputed from its stored input) and "auto"
    equal the plain scan: the same result and the same gradient to round-off."""
    from jaxmpm.run.driver import nested_sizes

    assert nested_sizes(7) == (3, 3) and nested_sizes(9) == (3, 3) and nested_sizes(1) == (1, 1)
    (a, ta), ga = jax.value_and_grad(_checkpointed_loss(small, mode), has_aux=True)(1000.0)
    (b, tb), gb = plain_scan_gradient
    assert float(ta) == float(tb) and float(ta) < 1.5  # falls short of t_end: padding must not step
    np.testing.assert_allclose(float(a), float(b), rtol=1e-13)
    assert float(gb) != 0.0
    np.testing.assert_allclose(float(ga), float(gb), rtol=1e-10)


def test_auto_checkpointing_stores_each_step_only_within_its_memory_budget(small, monkeypatch):
    """checkpoint="auto" is "steps" while n_steps stored States (times an ensemble's members) fit
    in AUTO_STEPS_BYTES, "nested" beyond; the other names map as documented."""
    sim = importlib.import_module("jaxmpm.run.driver")  # the module (jaxmpm.simulate is the function)

    scene, params, state = small
    one = sim.state_bytes(state)
    assert one == sum(np.asarray(a).nbytes for a in jax.tree.leaves(state))
    monkeypatch.setattr(sim, "AUTO_STEPS_BYTES", 10 * one)
    assert sim.checkpoint_mode("auto", state, 10) == "steps"
    assert sim.checkpoint_mode("auto", state, 11) == "nested"
    assert sim.checkpoint_mode("auto", state, 5, copies=2) == "steps"
    assert sim.checkpoint_mode("auto", state, 5, copies=3) == "nested"
    assert sim.checkpoint_mode(True) == "nested" and sim.checkpoint_mode(False) is False
    assert sim.checkpoint_mode(None) is False and sim.checkpoint_mode("steps") == "steps"


def test_a_default_gradient_stores_step_inputs_not_every_intermediate(small):
    """simulate's default checkpointing is "auto": a gradient through a run with default arguments
    keeps one State per step, where checkpoint=False keeps every step's intermediates (a few MiB
    per step on the built-in scenes, and slower to read back than the step is to recompute:
    benchmarks/NOTES.md). Measured by XLA's buffer assignment of the compiled gradient."""
    scene, params, state = small

    def temp_bytes(**checkpoint):
        def loss(E):
            p = params.with_constant("disk_a", "E", E)
            final, _ = jaxmpm.simulate(scene, p, state, t_end=1.5, n_out=1, n_steps=14, **checkpoint)
            return jnp.sum(final.mass * final.x[:, 1])

        return jax.jit(jax.grad(loss)).lower(1000.0).compile().memory_analysis().temp_size_in_bytes

    default, stored = temp_bytes(), temp_bytes(checkpoint=False)
    states = 14 * importlib.import_module("jaxmpm.run.driver").state_bytes(state)
    assert states <= default < 0.25 * stored, (default, stored, states)


def test_jaxmpm_jit_turns_off_ynnpack_fusions_and_gives_the_same_step(small):
    """jaxmpm.jit compiles with XLA's YNNPACK fusions off on the CPU (jaxmpm/compile.py): the
    compiled program has none of them, and the step's result is jax.jit's to round-off."""
    scene, params, state = small
    if jax.default_backend() != "cpu" or jaxmpm.numerics.compile.compiler_options() is None:
        pytest.skip("the option is for XLA's CPU backend, where this XLA knows it")
    step = jaxmpm.make_step(scene)
    fast, plain = jaxmpm.jit(step), jax.jit(step)
    assert "ynn_fusion" not in fast.lower(params, state).compile().as_text()
    assert_same_step(scene, params, state, fast(params, state), plain(params, state))


def _derivatives(small, kinds):
    """Derivatives of 14 steps in 2 outputs ("steps" checkpointing) with respect to E (the state
    without tangents at the start), a scale of the initial velocities (only v with one) and a
    given dt: reverse mode (also with the CFL step, where t takes a tangent), forward mode, and
    reverse mode under vmap. kinds: which of them."""
    scene, params, state = small

    def loss(E, a, dt):
        p = params.with_constant("disk_a", "E", E).with_constant("disk_b", "E", E)
        final, hist = jaxmpm.simulate(
            scene,
            p,
            dataclasses.replace(state, v=a * state.v),
            t_end=1.5,
            n_out=2,
            n_steps=14,
            dt=dt,
            checkpoint="steps",
            allow_short=True,
        )
        return jnp.sum(final.mass * final.x[:, 0] * final.x[:, 1]) + jnp.sum(hist.stress[1, :, 0, 0]) * 1e-3

    args = (1000.0, 1.0, 0.1)
    cfl = lambda E, a: loss(E, a, None)
    every = dict(
        reverse=lambda: jax.grad(loss, argnums=(0, 1, 2))(*args),
        reverse_cfl_dt=lambda: jax.grad(cfl, argnums=(0, 1))(1000.0, 1.0),
        forward=lambda: jax.jvp(loss, args, (1.0, 0.5, 0.01))[1],
        forward_E_only=lambda: jax.jvp(lambda E: loss(E, *args[1:]), (1000.0,), (1.0,))[1],
        vmapped=lambda: jax.vmap(jax.grad(loss), in_axes=(0, None, None))(jnp.array([900.0, 1000.0]), *args[1:]),
    )
    return {k: every[k]() for k in kinds}


@pytest.mark.parametrize(
    "kinds",
    [
        pytest.param(("reverse", "reverse_cfl_dt", "forward"), marks=pytest.mark.slow),
        pytest.param(("forward_E_only", "vmapped"), marks=pytest.mark.slow),
    ],
)
def test_marking_the_evolving_tangents_changes_no_derivative(small, monkeypatch, kinds):
    """`jaxmpm.run.tangents.evolving_tangents` (used by simulate) gives the state's fields their tangents before the scans (so
    that JAX linearizes each scan's body once): every derivative equals the one without it, for
    derivatives with respect to parameters only, to the initial state and to dt (where t keeps its
    own tangent), in both modes and under vmap."""
    sim = importlib.import_module("jaxmpm.run.driver")
    marked = _derivatives(small, kinds)
    monkeypatch.setattr(sim, "evolving_tangents", lambda fixed_dt, state, inputs: state)
    sim.fixed_fn.cache_clear()
    plain = _derivatives(small, kinds)
    sim.fixed_fn.cache_clear()
    for key in plain:
        for m, p in zip(jax.tree.leaves(marked[key]), jax.tree.leaves(plain[key])):
            assert np.all(np.isfinite(np.asarray(p))) and np.any(np.asarray(p) != 0), key
            np.testing.assert_allclose(np.asarray(m), np.asarray(p), rtol=1e-12, atol=0, err_msg=key)


def test_jaxmpm_jit_nested_in_another_jit_traces_its_function_once():
    """jaxmpm.jit inside another jit cannot take its compiler options (XLA takes them for the
    top-level computation only) and runs as a plain jax.jit: it must find that out before tracing
    the function, not by tracing it with the options and again without (under grad, both traces
    were linearized: the debris cloud's gradient traced for 12 s where 6.5 s do)."""
    calls = []

    @jaxmpm.jit
    def f(x):
        calls.append(1)
        return jnp.sin(x) * x

    assert float(jax.jit(jax.grad(f))(0.3)) == pytest.approx(np.cos(0.3) * 0.3 + np.sin(0.3), rel=1e-6)
    assert len(calls) == 1
    assert float(f(0.4)) == pytest.approx(np.sin(0.4) * 0.4, rel=1e-6)  # top level: with the options
    assert len(calls) == 2


def test_marked_tangents_carry_no_infinity_into_a_derivative(small):
    """The zero that `jaxmpm.run.tangents.evolving_tangents` (used by simulate) adds to the state's tangents is selected, not a
    product with 0: an infinite cotangent of a field that does not depend on the parameter (here x,
    for a derivative with respect to E) leaves the derivative what it is, not NaN; so does an
    infinite input tangent in forward mode."""
    sim = importlib.import_module("jaxmpm.run.driver")
    _, params, state = small
    marked_x = lambda E: sim.evolving_tangents(False, state, (E,)).x
    assert float(jax.grad(lambda E: jnp.sum(marked_x(E) * jnp.inf) + E**2)(3.0)) == 6.0
    x_dot = jax.jvp(marked_x, (3.0,), (jnp.inf,))[1]
    assert x_dot.shape == state.x.shape and np.all(np.asarray(x_dot) == 0.0)
