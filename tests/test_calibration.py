"""calibration/: the packaged experiment table, its checks, the batched runs it stands on (ensemble,
sharding), the debris cloud's C_h sweep, and the gradient of the fit's loss."""

import dataclasses
import functools
import os
import re
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from calibration import data

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "piekutowski_debris_cloud.csv"


def test_packaged_table_equals_the_shared_data():
    if not SHARED.exists():
        pytest.skip(f"{SHARED} not present (only beside the project's shared folder)")
    assert data.DEFAULT_CSV.read_bytes() == SHARED.read_bytes()
    m = data.load()
    np.testing.assert_array_equal(m.experiment, [6.3, 6.1, 3.9])
    np.testing.assert_array_equal(m.seed[0.02], [6.29, 5.97, 3.92])
    assert sorted(m.seed) == [0.02, 0.15, 0.5, 1.0]


GOOD = "point,experiment_km_s,ch_0.02\n1,6.3,6.29\n2,6.1,5.97\n4,3.9,3.92\n"


@pytest.mark.parametrize(
    "text, match",
    [
        (GOOD.replace("experiment_km_s", "exp"), "column 'experiment_km_s' is missing"),
        (GOOD.replace("6.1,", "fast,"), r"row 2, column 'experiment_km_s': 'fast' is not a number"),
        (GOOD.replace("3.92", "-3.92"), r"row 3, column 'ch_0.02': -3.92 km/s is invalid: allowed \(0, 20"),
        (GOOD.replace("\n4,", "\n3,"), r"row 3, column 'point': point 3 is unknown: allowed \(1, 2, 4\)"),
        (GOOD.replace("\n4,3.9,3.92\n", "\n"), "point 4 is missing"),
        (GOOD.replace("\n2,", "\n1,"), "row 2, column 'point': point 1 is repeated"),
        (GOOD.replace("ch_0.02", "ch_x"), "column 'ch_x': 'x' is not a value of C_h"),
        (GOOD.replace("6.3,6.29", "6.3"), "row 1: has 2 values, the header 3"),
    ],
)
def test_bad_tables_are_refused_naming_row_and_column(tmp_path, text, match):
    path = tmp_path / "t.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        data.load(path)


def _small_cloud(t_end=3e-7):
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2, t_end=t_end)
    params = jaxmpm.default_params(scene)
    return scene, params, jaxmpm.init_state(scene, params)


def test_ensemble_equals_the_single_runs():
    scene, params, s0 = _small_cloud()
    batch = jaxmpm.batch.sweep(params, c_h=[0.02, 0.15, 0.5, 1.0], drag_coefficient=[0.5, 1.0, 2.0, 4.0])
    n = 40
    final, hist = jaxmpm.ensemble(scene, batch, t_end=3e-7, n_out=2, n_steps=n)
    assert final.x.shape[0] == 4 and hist.x.shape[:2] == (4, 3)
    for i in range(4):
        f1, h1 = jaxmpm.simulate(scene, jaxmpm.batch.member(batch, i), s0, t_end=3e-7, n_out=2, n_steps=n)
        for a, b in zip(jax.tree.leaves(jaxmpm.batch.member((final, hist), i)), jax.tree.leaves((f1, h1))):
            np.testing.assert_allclose(
                np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12 * float(np.max(np.abs(b)) + 1e-30)
            )
    # the members differ (the sweep is not a broadcast of one)
    assert float(jnp.max(jnp.abs(final.v[0] - final.v[3]))) > 1.0


def test_sweep_and_batch_errors():
    scene, params, _ = _small_cloud()
    with pytest.raises(ValueError, match="'C_h' is not a Params field"):
        jaxmpm.batch.sweep(params, C_h=[1.0])
    with pytest.raises(ValueError, match="c_h has 2 values, another field 3"):
        jaxmpm.batch.sweep(params, drag_coefficient=[1.0, 2.0, 3.0], c_h=[0.1, 0.2])
    bad = dataclasses.replace(jaxmpm.batch.sweep(params, c_h=[0.1, 0.2]), cfl=params.cfl)
    with pytest.raises(ValueError, match="one common leading"):
        jaxmpm.ensemble(scene, bad, t_end=1e-7)


SHARD_SCRIPT = """
import jax, numpy as np, jaxmpm
assert len(jax.devices()) == 2, jax.devices()
scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2, t_end=2e-7)
params = jaxmpm.default_params(scene)
batch = jaxmpm.batch.sweep(params, c_h=[0.02, 0.15, 0.5])     # 3 members on 2 devices: padded
a, _ = jaxmpm.ensemble(scene, batch, t_end=2e-7, n_out=1, n_steps=30, shard=True)
b, _ = jaxmpm.ensemble(scene, batch, t_end=2e-7, n_out=1, n_steps=30, shard=False)
assert a.x.shape[0] == 3
for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
    np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-9, atol=1e-12 * float(np.max(np.abs(np.asarray(y))) + 1e-30))
print("sharded == unsharded")
"""


@pytest.mark.slow  # 43 s; the two-device step is checked in the default run (test_distributed)
def test_sharded_ensemble_on_two_host_devices_equals_the_unsharded_one():
    env = dict(
        os.environ,
        XLA_FLAGS=(os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip(),
        JAX_PLATFORMS="cpu",
        JAX_ENABLE_X64="1",
    )
    r = subprocess.run([sys.executable, "-c", SHARD_SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "sharded == unsharded" in r.stdout


@functools.lru_cache(maxsize=2)
def _sweep(fragmentation):
    """The seed's C_h sweep on the coarse cloud (one field, float64 as all tests, 6 us), one vmapped call."""
    from calibration.model import CloudModel

    model = CloudModel.build(resolution=0.75, fields=1, fragmentation=fragmentation)
    values = np.array([0.02, 0.15, 0.5, 1.0])
    batch = jaxmpm.batch.sweep(model.params, c_h=values)
    final, hist = jaxmpm.ensemble(
        model.scene, batch, model.state, t_end=model.t_end, n_out=model.n_out, n_steps=model.n_steps, allow_short=True
    )
    v = np.asarray(jax.vmap(model.velocities_of_history)(hist))
    print(f"fragmentation {fragmentation!r}: points 1, 2, 4 (km/s) for C_h = {values.tolist()}:\n{v.round(3)}")
    return model, final, v


@pytest.fixture(scope="module")
def ch_sweep():
    return _sweep("failed")


@pytest.fixture(scope="module")
def ch_sweep_plastic():
    return _sweep("plastic")


@pytest.mark.slow
@pytest.mark.parametrize("fragmentation", ["failed", "plastic"])
def test_coarse_cloud_sweep_is_finite_and_conserves_axial_momentum(fragmentation):
    model, final, v = _sweep(fragmentation)
    assert np.all(np.asarray(final.t) >= model.t_end * (1 - 1e-9)), np.asarray(final.t)
    assert all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(final))
    p0 = float(jaxmpm.diagnostics.momentum(model.state)[1])
    for i in range(4):
        p1 = float(jaxmpm.diagnostics.momentum(jaxmpm.batch.member(final, i))[1])
        assert abs(p1 / p0 - 1) < 0.005
    assert np.all((v > 3.0) & (v < 7.0)), v


@pytest.mark.slow
def test_coarse_tensile_cloud_creates_no_energy_and_its_rear_follows_c_h():
    """fragmentation 'tensile', the seed's C_h: no member gains energy (kinetic + internal within
    [-2%, +0.1%] of the start; measured -0.4 to -0.6%), no particle ends with a negative internal
    energy, and point 4 (the projectile's rear) rises with C_h (measured 5.23, 5.78, 6.00, 5.97 km/s
    by the host driver). Before the artificial viscosity was taken from the velocity field's
    compression, C_h = 0.15 gave point 4 at 0.99 km/s: a fragment thrown upstream by the viscous
    pressure of its own relaxation (docs/closure.md)."""
    model, final, v = _sweep("tensile")
    assert np.all(np.asarray(final.t) >= model.t_end * (1 - 1e-9)), np.asarray(final.t)
    assert all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(final))
    e0 = float(jaxmpm.diagnostics.kinetic_energy(model.state) + jaxmpm.diagnostics.internal_energy(model.state))
    for i in range(4):
        m = jaxmpm.batch.member(final, i)
        e1 = float(jaxmpm.diagnostics.kinetic_energy(m) + jaxmpm.diagnostics.internal_energy(m))
        assert -0.02 < e1 / e0 - 1 < 1e-3, (i, e1 / e0 - 1)
        assert float(m.energy.min()) > 0.0, (i, float(m.energy.min()))
    assert v[-1, 2] > v[0, 2] + 0.5 and np.all(v[1:, 2] > 5.0), v[:, 2]


@pytest.mark.slow
def test_coarse_cloud_with_the_seeds_closure_follows_the_seeds_trend_in_c_h(ch_sweep_plastic):
    """With fragmentation = 'plastic' (the seed's E5) point 4 (rear of the projectile) speeds up as
    C_h grows, as in the seed (3.92, 4.09, 6.1, 6.11 km/s; measured 5.85, 5.91, 6.07, 6.18 before
    the walls)."""
    _, _, v = ch_sweep_plastic
    assert np.all(np.diff(v[:, 2]) > 0), v[:, 2]


@pytest.mark.slow
def test_coarse_cloud_slows_the_projectile_rear_below_the_front(ch_sweep):
    """Default closure (fragmentation 'failed'), C_h = 0.02: the projectile's rear (point 4) is
    slower than the fronts (points 1, 2) by more than 0.3 km/s, as in the experiment (3.9 against
    6.3, 6.1; measured 5.10 against 5.59, 5.59 at this resolution, 4.10 against 5.62, 5.74 at
    resolution 2). With the seed's closure it was the fastest (5.85 against 5.24, 5.25)."""
    _, _, v = ch_sweep
    assert v[0, 2] < min(v[0, 0], v[0, 1]) - 0.3, v[0]


def test_ensemble_shows_its_steps_and_compiles_once_per_setting(capsys):
    """progress (the default) draws a bar of the batch's steps, counted from inside the compiled
    run, and changes no result; a second call with the same setting does not compile again."""
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25)
    params = jaxmpm.default_params(scene)
    batch = jaxmpm.batch.sweep(params, cfl=[0.2, 0.3])
    capsys.readouterr()
    shown, _ = jaxmpm.ensemble(scene, batch, t_end=0.2, n_out=2, n_steps=40)
    err = capsys.readouterr().err
    assert "elastic_impact x2" in err and "40/40" in err
    quiet, _ = jaxmpm.ensemble(scene, batch, t_end=0.2, n_out=2, n_steps=40, progress=False)
    assert "40/40" not in capsys.readouterr().err
    np.testing.assert_array_equal(np.asarray(shown.x), np.asarray(quiet.x))
    before = jaxmpm.batch._members_fn.cache_info().hits
    jaxmpm.ensemble(scene, jaxmpm.batch.sweep(params, cfl=[0.25, 0.15]), t_end=0.2, n_out=2, n_steps=40, progress=False)
    assert jaxmpm.batch._members_fn.cache_info().hits == before + 1


def test_ensemble_names_a_member_that_falls_short_of_t_end():
    scene, params, s0 = _small_cloud()
    batch = jaxmpm.batch.sweep(params, c_h=[0.02, 0.15])
    with pytest.raises(RuntimeError, match=r"member\(s\) \[0, 1\] reached only t = .* pass a larger n_steps"):
        jaxmpm.ensemble(scene, batch, t_end=3e-7, n_out=1, n_steps=3)


@pytest.mark.slow
def test_ensemble_runs_again_when_its_own_plan_falls_short():
    """Without n_steps, ensemble plans them from the initial CFL step with a 25% margin; the
    impact's step shrinks more than that by 3e-7 s (31 planned steps reach 2.976e-7 s). It then
    runs the batch again with more steps, says so, and every member reaches t_end."""
    scene, params, _ = _small_cloud()
    batch = jaxmpm.batch.sweep(params, c_h=[0.1, 0.2])
    with pytest.warns(
        RuntimeWarning, match=r"planned n_steps = (\d+) reached only .* running the batch again with n_steps = (\d+)"
    ) as rec:
        final, hist = jaxmpm.ensemble(scene, batch, t_end=3e-7, n_out=2)
    planned, replanned = (
        int(k) for k in re.search(r"n_steps = (\d+) reached.* n_steps = (\d+)", str(rec[0].message)).groups()
    )
    assert replanned > planned
    np.testing.assert_allclose(np.asarray(final.t), 3e-7, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(hist.t)[:, -1], 3e-7, rtol=1e-9)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known limitation, documented in docs/limitations.md (issue 7): "
    "at resolution 0.75 the debris front (point 1) leads the "
    "projectile's front (point 2) by 3 m/s only (5.593, 5.590 km/s at C_h = 0.02; experiment 6.3, "
    "6.1: 0.2 km/s); at resolution 2 point 2 leads (5.62, 5.74)",
)
def test_coarse_cloud_debris_front_leads_the_projectile_front(ch_sweep):
    """The experiment's debris front leads the projectile's front by 0.2 km/s; at least half that.
    (A bare v1 > v2 passed by 3 m/s once the closure's ambient became per phase, E8, 2026-12-03.)"""
    _, _, v = ch_sweep
    assert v[0, 0] > v[0, 1] + 0.1, v[0]


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known limitation, documented in docs/limitations.md (issues 7, 11): "
    "the coarse cloud's response to C_d is a sawtooth: smooth "
    "pieces about 1e-3 wide in log C_d joined by jumps, so AD (the slope of a piece, which central "
    "differences at step 1e-6 confirm: test below) and differences at steps 0.02 and 0.005 (the slope "
    "across jumps) disagree: d loss / d log C_d = 1.00 by AD against 1.04 and 0.91. The jumps come "
    "from particle-level switches the drag moves in time, e.g. a particle entering a cell whose far "
    "node has no other mass of its field, whose velocity then enters the DDMP velocity gradient at "
    "once, or a molten projectile particle whose Johnson-Cook damage starts to grow one step "
    "earlier when its pressure changes sign. The C_h component agrees at all steps (0.0331)",
)
def test_gradient_of_the_fit_loss_matches_finite_differences():
    """float64, two fields, 3 us, at (C_d, C_h) = (1, 0.15): both components of d loss / d log
    (C_d, C_h) within 5% of central differences at steps 0.02 and 0.005 (the issue's check)."""
    from calibration.fit import loss_fn
    from calibration.model import CloudModel

    model = CloudModel.build(resolution=0.75, fields=2, t_end=3e-6, n_out=6)
    target = data.load().experiment
    loss = jax.jit(lambda th: loss_fn(model.velocities, target)(th)[0])
    theta = jnp.log(jnp.array([1.0, 0.15]))
    g = np.asarray(jax.jit(jax.grad(lambda th: loss_fn(model.velocities, target)(th)[0]))(theta))
    assert g.dtype == np.float64 and np.all(np.isfinite(g))
    for eps in (0.02, 0.005):
        fd = np.array([(float(loss(theta + eps * e)) - float(loss(theta - eps * e))) / (2 * eps) for e in np.eye(2)])
        np.testing.assert_allclose(g, fd, rtol=0.05, err_msg=f"step {eps}")


@pytest.mark.slow
@pytest.mark.parametrize("fragmentation", ["failed", "tensile"])
def test_gradient_of_the_fit_loss_matches_small_step_differences(fragmentation):
    """The issue's check of the fit loss's gradient (float64, two fields, 3 us, at (C_d, C_h) =
    (1, 0.15)) against central differences at step 1e-6 in (log C_d, log C_h): within 1e-3
    (measured within 1e-4 with 'failed', 1.4e-5 and 1.4e-7 with 'tensile'; the issue asked for 5%).
    At this step the differences stay on the smooth piece of the response that AD differentiates;
    larger steps cross its jumps (the strict xfails above and below)."""
    from calibration.fit import loss_fn
    from calibration.model import CloudModel

    model = CloudModel.build(resolution=0.75, fields=2, t_end=3e-6, n_out=6, fragmentation=fragmentation)
    target = data.load().experiment
    loss = jax.jit(lambda th: loss_fn(model.velocities, target)(th)[0])
    theta = jnp.log(jnp.array([1.0, 0.15]))
    g = np.asarray(jax.jit(jax.grad(lambda th: loss_fn(model.velocities, target)(th)[0]))(theta))
    eps = 1e-6
    fd = np.array([(float(loss(theta + eps * e)) - float(loss(theta - eps * e))) / (2 * eps) for e in np.eye(2)])
    print("d loss / d log (C_d, C_h): AD", g, "differences at 1e-6", fd)
    assert abs(g[0]) > 0.1 and abs(g[1]) > 0.01
    np.testing.assert_allclose(g, fd, rtol=1e-3)


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known limitation, documented in docs/closure.md: with fragmentation 'tensile' the coarse "
    "cloud's loss is rough in both coefficients at steps of 0.005-0.02 in log (C_d, C_h): AD gives "
    "(0.183, 2.118) at (1, 0.15), central differences (0.791, 1.354) at step 0.005 and (-2.457, 2.429) "
    "at 0.02, while at 1e-6 they agree with AD within 1.4e-5 (the test above). Particles whose "
    "tension-counted plastic strain starts one step earlier or later switch the pressure factor",
)
def test_gradient_of_the_tensile_fit_loss_matches_finite_differences():
    """float64, two fields, 3 us, fragmentation 'tensile', at (C_d, C_h) = (1, 0.15): both
    components of d loss / d log (C_d, C_h) within 5% of central differences at steps 0.02 and 0.005."""
    from calibration.fit import loss_fn
    from calibration.model import CloudModel

    model = CloudModel.build(resolution=0.75, fields=2, t_end=3e-6, n_out=6, fragmentation="tensile")
    target = data.load().experiment
    loss = jax.jit(lambda th: loss_fn(model.velocities, target)(th)[0])
    theta = jnp.log(jnp.array([1.0, 0.15]))
    g = np.asarray(jax.jit(jax.grad(lambda th: loss_fn(model.velocities, target)(th)[0]))(theta))
    assert np.all(np.isfinite(g))
    for eps in (0.02, 0.005):
        fd = np.array([(float(loss(theta + eps * e)) - float(loss(theta - eps * e))) / (2 * eps) for e in np.eye(2)])
        np.testing.assert_allclose(g, fd, rtol=0.05, err_msg=f"step {eps}")


@pytest.mark.parametrize(
    "argv, match",
    [
        (["fit", "--start", "1.0"], r"--start '1.0' is invalid: allowed two numbers 'C_d,C_h'"),
        (["fit", "--start=-1,0.1"], r"--start '-1,0.1' is invalid: allowed C_d > 0 and C_h > 0"),
        (["table", "--c-h", "0.1,-0.5"], r"--c-h '0.1,-0.5' is invalid: allowed C_h values > 0"),
        (["fit", "--iterations", "0"], r"--iterations 0 is invalid: allowed an integer >= 1"),
        (
            ["table", "--drag=-1", "--fields", "2", "--c-h", "0.1"],
            r"--drag -1.0 is invalid: allowed a finite number > 0",
        ),
        (["table", "--drag", "nan"], r"--drag nan is invalid: allowed a finite number > 0"),
        (["fit", "--learning-rate=-1"], r"--learning-rate -1.0 is invalid: allowed a finite number > 0"),
        (["fit", "--learning-rate", "0"], r"--learning-rate 0.0 is invalid: allowed a finite number > 0"),
        (["fit", "--learning-rate", "nan"], r"--learning-rate nan is invalid: allowed a finite number > 0"),
        (["fit", "--fields", "1"], r"--fields 1 is invalid: allowed 2 \(C_d, the drag between the two velocity fields"),
        (["table", "--fields", "3"], r"--fields 3 is invalid: allowed 1 \| 2"),
        (["table", "--drag-heating"], r"--drag-heating is invalid with --fields 1: allowed only with --fields 2"),
        (["table", "--c-h", "a,b"], r"--c-h 'a,b' is invalid: allowed comma-separated numbers"),
        (["table", "--c-h", ""], r"--c-h '' is invalid: allowed comma-separated numbers"),
        (["table", "--c-h", "0.1,inf"], r"--c-h '0.1,inf' is invalid: allowed C_h values > 0"),
        (["fit", "--start", "inf,0.1"], r"--start 'inf,0.1' is invalid: allowed C_d > 0 and C_h > 0"),
        (
            ["table", "--resolution", "0.5"],
            r"--resolution 0.5 is invalid: .* allowed a finite number >= 0.724 \(4 cells across the plate\)",
        ),
        (["table", "--resolution", "nan"], r"--resolution nan is invalid: allowed a finite number > 0"),
        (["fit", "--t-end=-1"], r"--t-end -1.0 is invalid: allowed a finite number > 0 \(s\)"),
        (["fit", "--landscape", "1"], r"--landscape 1 is invalid: allowed 0 \(none\) or an integer >= 2"),
        (["fit", "--landscape-cd", "1", "0.5"], r"--landscape-cd 1.0 0.5 is invalid: allowed LO HI with 0 < LO < HI"),
        (["fit", "--landscape-ch", "0", "1"], r"--landscape-ch 0.0 1.0 is invalid: allowed LO HI with 0 < LO < HI"),
        (["table", "--step-safety", "0.5"], r"--step-safety 0.5 is invalid: allowed a finite number >= 1"),
        (
            ["table", "--artificial-viscosity", "0.2", "-1"],
            r"--artificial-viscosity 0.2 -1.0 is invalid: allowed two finite numbers >= 0",
        ),
        (["fit", "--starts", "0"], r"--starts 0 is invalid: allowed an integer >= 1"),
        (
            ["fit", "--starts", "3", "--method", "lbfgs"],
            r"--starts 3 is invalid with --method lbfgs: allowed only with --method adam",
        ),
        (
            ["table", "--data", "no/such/table.csv"],
            r"--data no/such/table.csv: no such file \(allowed the path of a CSV",
        ),
    ],
)
def test_calibration_command_refuses_bad_options(tmp_path, capsys, argv, match):
    """Refused with status 2 and a message naming the option and its range, before any run and
    before the --out folder is created."""
    import re

    from calibration.__main__ import main

    assert main(argv + ["--out", str(tmp_path / "new")]) == 2
    assert re.search(match, capsys.readouterr().err)
    assert not (tmp_path / "new").exists()


def test_calibration_command_refuses_an_out_path_through_a_file(tmp_path, capsys):
    from calibration.__main__ import main

    afile = tmp_path / "afile"
    afile.write_text("kept")
    for out in (afile, afile / "sub"):
        assert main(["table", "--out", str(out)]) == 2
        assert f"--out {out} is invalid: {afile} exists and is not a folder" in capsys.readouterr().err
    assert afile.read_text() == "kept"


def test_missing_or_non_file_table_is_refused_naming_it(tmp_path, capsys):
    from calibration.__main__ import main

    with pytest.raises(FileNotFoundError, match=f"{tmp_path / 'nope.csv'}: no such file"):
        data.load(tmp_path / "nope.csv")
    with pytest.raises(ValueError, match=f"{tmp_path} is not a file"):
        data.load(tmp_path)
    assert main(["fit", "--data", str(tmp_path), "--out", str(tmp_path / "new")]) == 2
    assert f"error: --data {tmp_path} is not a file" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_calibration_command_never_overwrites_a_previous_result(tmp_path, capsys):
    from calibration.__main__ import main

    old = tmp_path / "previous"
    old.mkdir()
    (old / "result.json").write_text("{}")
    assert main(["table", "--out", str(old)]) == 2
    assert "exists and is not empty: a previous result is never overwritten" in capsys.readouterr().err
    assert (old / "result.json").read_text() == "{}"


TRUTH = (1.0, 0.15)


@pytest.fixture(scope="module")
def synthetic_fit():
    """L-BFGS on the small two-phase scene of calibration.synthetic, observables generated at
    TRUTH, started 2x away in both C_d and C_h."""
    from calibration.fit import fit
    from calibration.model import theta_of
    from calibration.synthetic import DebrisInWaterModel

    model = DebrisInWaterModel.build()
    target = jax.jit(model.observables)(theta_of(*TRUTH))
    start = theta_of(2 * TRUTH[0], 2 * TRUTH[1])
    return (
        model,
        target,
        start,
        fit(model.observables, target, start, iterations=20, method="lbfgs", tol=1e-12, progress=False),
    )


@pytest.mark.slow
def test_synthetic_recovery_from_two_times_away(synthetic_fit):
    """Both C_d and C_h recovered within 5% from a start at twice their values (measured: 1.2e-7,
    10 L-BFGS iterations, 20 loss-and-gradient evaluations). C_h is seen through the block's early
    pressure (calibration.synthetic's observable 2): at t_end alone it is not identifiable."""
    _, _, _, res = synthetic_fit
    err = res.values / np.asarray(TRUTH) - 1
    assert np.all(np.abs(err) < 0.05), (res.values, res.stopped)
    assert res.history[0]["loss"] > 1e3 * res.loss  # it did move


@pytest.mark.slow
def test_synthetic_loss_gradient_matches_finite_differences(synthetic_fit):
    """The gradient of the loss at the start (the fit's first evaluation, jax.value_and_grad
    through the checkpointed simulate) against central differences at two step sizes: within 0.2%
    (measured: 1.7e-4 and 3.3e-4 at step 1e-3, 4.6e-5 and 2.8e-5 at 3e-4, 5e-6 at 1e-4; steps of
    3e-3 and more straddle small jumps of the observables: 3.3% at 3e-3)."""
    from calibration.fit import loss_fn

    model, target, start, res = synthetic_fit
    g = np.asarray(res.history[0]["grad"])
    loss = jax.jit(lambda th: loss_fn(model.observables, target)(th)[0])
    for eps in (1e-3, 3e-4):
        fd = np.array([(float(loss(start + eps * e)) - float(loss(start - eps * e))) / (2 * eps) for e in np.eye(2)])
        np.testing.assert_allclose(g, fd, rtol=2e-3, err_msg=f"step {eps}")


def test_fit_refuses_an_unknown_method():
    from calibration.fit import fit

    with pytest.raises(ValueError, match=r"method = 'sgd' is invalid: allowed adam \| lbfgs"):
        fit(lambda th: th, np.zeros(2), np.zeros(2), method="sgd")


@pytest.mark.parametrize(
    "options, match",
    [
        (dict(learning_rate=-1.0), r"learning_rate = -1.0 is invalid: allowed a finite number > 0"),
        (dict(learning_rate=0.0), r"learning_rate = 0.0 is invalid: allowed a finite number > 0"),
        (dict(learning_rate=np.nan), r"learning_rate = nan is invalid: allowed a finite number > 0"),
        (dict(decay=0.0), r"decay = 0.0 is invalid: allowed a number in \(0, 1\]"),
        (dict(decay=1.5), r"decay = 1.5 is invalid: allowed a number in \(0, 1\]"),
        (dict(tol=-1.0), r"tol = -1.0 is invalid: allowed a finite number >= 0"),
        (dict(rtol=np.nan), r"rtol = nan is invalid: allowed a finite number >= 0"),
        (dict(patience=0), r"patience = 0 is invalid: allowed an integer >= 1"),
        (dict(theta0=np.zeros(3)), r"theta0 = .* is invalid: allowed finite numbers of shape \(2,\)"),
        (dict(theta0=[np.nan, 0.0]), r"theta0 = .* is invalid: allowed finite numbers of shape \(2,\)"),
        (
            dict(target=np.zeros(4)),
            r"target of shape \(4,\) is invalid: allowed the shape of velocities\(theta0\), \(3,\)",
        ),
        (dict(target=[6.3, np.inf, 3.9]), r"target = .* is invalid: allowed finite numbers"),
        (
            dict(weights=[-1.0, 1.0, 1.0]),
            r"weights = .* is invalid: allowed None or finite numbers >= 0, not all 0, "
            r"of target's shape \(3,\)",
        ),
        (dict(weights=[0.0, 0.0, 0.0]), r"weights = .* is invalid: allowed None or finite numbers >= 0, not all 0"),
        (dict(weights=[1.0, 1.0]), r"weights = .* is invalid: .* of target's shape \(3,\)"),
    ],
)
def test_fit_refuses_bad_arguments_before_any_run(options, match):
    """ValueError naming the argument and its range; the model is never called (only traced for its
    output's shape)."""
    from calibration.fit import fit

    calls = []

    def velocities(theta):
        calls.append(isinstance(theta, jax.core.Tracer))
        return jnp.stack([theta[0], theta[1], theta[0] + theta[1]])

    args = dict(target=np.array([6.3, 6.1, 3.9]), theta0=np.zeros(2)) | options
    with pytest.raises(ValueError, match=match):
        fit(velocities, progress=False, **args)
    assert all(calls)


@pytest.mark.slow
def test_the_fits_checks_after_the_optimiser_follow_no_progress(capfd):
    """`fit --no-progress` runs the fitted point once more (`checks`) and the landscape
    (`velocities_batch`): both without a progress bar when asked, with one by default."""
    from calibration.model import CloudModel

    model = CloudModel.build(resolution=0.75, fields=2, t_end=2e-7, n_out=2, drag_heating=True)
    assert model.scene.drag_heating
    theta = np.log([1.0, 0.15])
    capfd.readouterr()
    assert model.reached(theta, progress=False) == pytest.approx(2e-7)
    np.asarray(model.velocities_batch(np.stack([theta, theta + 0.1]), allow_short=True, progress=False))
    assert "step/s" not in capfd.readouterr().err
    model.reached(theta)
    assert "step/s" in capfd.readouterr().err


def two_basins(theta):
    """Observables whose loss against TWO_BASIN_TARGET has two minima: theta_0 ~ +1 (loss 0) and
    theta_0 ~ -1 (loss ~0.36), theta_1 = 0 in both."""
    return jnp.stack([theta[0] ** 2, theta[1], 0.3 * (theta[0] - 1.0)])


TWO_BASIN_TARGET = np.array([1.0, 0.0, 0.0])


def test_multistart_runs_every_start_and_keeps_the_best():
    """`fit_starts` advances K starts in one vmapped step: each start's history equals the single
    `fit` from it (so every start ran, each on its own), the starts in the two basins end in their
    own minima, and the best kept is the one with the lowest loss (the second start here, not the
    first)."""
    from calibration.fit import fit, fit_starts

    jax.config.update("jax_enable_x64", True)
    starts = np.array([[-2.0, 0.5], [2.0, -0.5], [-0.5, 1.0]])
    kw = dict(iterations=80, learning_rate=0.1, decay=0.99, progress=False)
    multi = fit_starts(two_basins, TWO_BASIN_TARGET, starts, **kw)
    assert len(multi.fits) == 3
    for k, start in enumerate(starts):
        alone = fit(two_basins, TWO_BASIN_TARGET, start, **kw)
        got = multi.fits[k]
        assert len(got.history) == len(alone.history) > 5, k
        np.testing.assert_allclose([h["loss"] for h in got.history], [h["loss"] for h in alone.history], rtol=1e-12)
        np.testing.assert_allclose(got.theta, alone.theta, rtol=1e-12)
        assert got.stopped == alone.stopped
    ends = np.array([f.theta[0] for f in multi.fits])
    assert ends[0] < -0.8 and ends[1] > 0.9 and ends[2] < -0.8, ends  # each in its own basin
    losses = [f.loss for f in multi.fits]
    assert multi.best == 1 == int(np.argmin(losses))
    assert multi.best_fit is multi.fits[1]
    assert multi.best_fit.loss < 1e-3 < min(losses[0], losses[2])


def test_multistart_refuses_bad_starts():
    from calibration.fit import fit_starts, spread_starts

    for bad in (np.zeros((0, 2)), np.zeros((2, 3)), [[0.0, np.nan]], np.zeros(2)):
        with pytest.raises(ValueError, match=r"(?s)theta0s = .* is invalid: allowed finite numbers of shape \(K, 2\)"):
            fit_starts(two_basins, TWO_BASIN_TARGET, bad, progress=False)
    with pytest.raises(ValueError, match=r"starts = 0 is invalid: allowed an integer >= 1"):
        spread_starts((1.0, 0.15), 0, (0.1, 10.0), (0.02, 1.0))


def test_spread_starts_fill_the_box_from_the_given_start():
    from calibration.fit import spread_starts

    th = spread_starts((1.0, 0.15), 5, (0.1, 10.0), (0.02, 1.0))
    assert th.shape == (5, 2)
    np.testing.assert_allclose(np.exp(th[0]), [1.0, 0.15])
    c = np.exp(th[1:])
    assert np.all((c[:, 0] >= 0.1) & (c[:, 0] <= 10.0) & (c[:, 1] >= 0.02) & (c[:, 1] <= 1.0))
    assert len(np.unique(np.round(th, 12), axis=0)) == 5  # all different
    np.testing.assert_array_equal(th, spread_starts((1.0, 0.15), 5, (0.1, 10.0), (0.02, 1.0)))  # reproducible


@pytest.mark.slow
def test_fit_command_with_starts_runs_every_start_and_reports_them(tmp_path, capsys):
    """`fit --starts 2` at the coarsest resolution and a short end time: both starts are run in one
    vmapped call (each has its iterations), all are reported in result.json, and the fitted values
    are those of the start with the lowest loss; the run at the fit reports the plate's lead."""
    import json

    from calibration.__main__ import main

    out = tmp_path / "fit"
    argv = ["fit", "--resolution", "0.75", "--t-end", "2e-7", "--starts", "2", "--iterations", "2"]
    assert main(["--no-cache"] + argv + ["--landscape", "0", "--no-progress", "--out", str(out)]) == 0
    result = json.loads((out / "result.json").read_text())
    starts = result["starts"]
    assert len(starts) == 2 and result["settings"]["starts"] == 2
    assert [s["iterations"] for s in starts] == [2, 2]
    assert starts[0]["start_C_d"] == pytest.approx(1.0) and starts[0]["start_C_h"] == pytest.approx(0.15)
    best = int(np.argmin([s["loss"] for s in starts]))
    assert [s["best"] for s in starts] == [k == best for k in range(2)]
    assert result["fitted"]["C_d"] == pytest.approx(starts[best]["C_d"], rel=1e-12)
    assert result["fitted"]["C_h"] == pytest.approx(starts[best]["C_h"], rel=1e-12)
    assert result["loss"] == pytest.approx(starts[best]["loss"], rel=1e-12)
    assert 0 < result["plate_lead_mm"] < 2.21 + 0.54  # 0.2 us in: the projectile has not reached the plate's rear
    printed = capsys.readouterr().out
    assert "2 starts in one vmapped call" in printed and f"plate lead {result['plate_lead_mm']:.2f} mm" in printed


def test_a_weak_drag_lets_the_projectile_through_the_plate_and_the_table_says_so():
    """In the experiment's cloud the plate's debris (the external bubble) leads and encloses the
    projectile's fragments, so point 1 is plate material. With two fields the exchange drag is what
    holds the projectile's material behind the plate's: resolution 0.75, 2 us, C_h = 0.15, at
    C_d = 1 the plate leads by 0.81 mm at the end; at C_d = 0.02 projectile material has passed
    through it (lead -2.5 mm) and the front (point 1) is projectile material at 7.5 km/s, faster
    than the impact (5.3 km/s at C_d = 1). `plate_lead` measures it, `table_batch` returns it from the same vmapped call,
    and the table and the fit warn."""
    from calibration.model import CloudModel, through_plate_warning

    model = CloudModel.build(resolution=0.75, fields=2, t_end=2e-6, fragmentation="tensile")
    v, lead = (np.asarray(a) for a in model.table_batch(np.log([[0.02, 0.15], [1.0, 0.15]]), progress=False))
    assert lead[0] < -1e-3 and lead[1] > 0.3e-3, lead
    assert v[0, 0] > 6.71 > 6.0 > v[1, 0], v
    warning = through_plate_warning([0.02, 1.0], lead, "C_d = ")
    assert warning.startswith("warning: at C_d = 0.02 projectile material has passed") and "C_d = 1" not in warning
    assert through_plate_warning(["the fit"], lead[:1]).startswith("warning: at the fit projectile material")
    assert through_plate_warning([1.0], lead[1:]).startswith("plate lead > 0 in every run")
