"""Restart files: a resumed run is bit-identical to an uninterrupted one; an interrupted write
leaves the previous restart file readable."""

import dataclasses
import warnings

import h5py
import numpy as np
import pytest

import jaxmpm
from jaxmpm import restart


@pytest.fixture()
def small():
    scene = dataclasses.replace(jaxmpm.load_scene("elastic_impact", resolution=0.25), t_end=1.5, n_out=3)
    params = jaxmpm.default_params(scene)
    return scene, params, jaxmpm.init_state(scene, params)


def test_resumed_run_is_bit_identical(small, tmp_path):
    scene, params, s0 = small
    full, hist_full = jaxmpm.simulate(scene, params, s0, progress=False, chunk=7)
    path = tmp_path / "run.restart.h5"

    class Stop(Exception):
        pass

    # interrupt the run in the middle of the second output interval
    calls = {"n": 0}
    real = restart.save

    def save_then_maybe_stop(*a, **k):
        real(*a, **k)
        calls["n"] += 1
        if calls["n"] == 6:
            raise Stop

    restart.save = save_then_maybe_stop
    try:
        with pytest.raises(Stop):
            jaxmpm.simulate(scene, params, s0, progress=False, chunk=7, restart_file=str(path), restart_every=2)
    finally:
        restart.save = real
    saved = restart.load(path)
    assert 0 < float(saved["state"].t) < scene.t_end and saved["next_out"] >= 1
    scene2, params2, final, hist = restart.resume(path, progress=False)
    assert scene2 == scene
    for a, b in zip(jaxmpm.State.__dataclass_fields__, jaxmpm.State.__dataclass_fields__):
        x, y = getattr(final, a), getattr(full, b)
        if x is not None:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    np.testing.assert_array_equal(np.asarray(hist.x), np.asarray(hist_full.x))
    np.testing.assert_array_equal(np.asarray(hist.t), np.asarray(hist_full.t))
    with warnings.catch_warnings():  # a complete run resumed: its saved results, no progress bar to clamp
        warnings.simplefilter("error")
        _, _, final2, hist2 = restart.resume(path, progress=True)
    np.testing.assert_array_equal(np.asarray(final2.x), np.asarray(full.x))
    np.testing.assert_array_equal(np.asarray(hist2.x), np.asarray(hist_full.x))


def test_interrupted_write_keeps_the_previous_restart_file(small, tmp_path, monkeypatch):
    scene, params, s0 = small
    path = tmp_path / "run.restart.h5"
    jaxmpm.simulate(scene, params, s0, t_end=0.5, n_out=1, progress=False, restart_file=str(path))
    before = restart.load(path)

    def broken_write_tree(group, tree):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(restart, "_write_tree", broken_write_tree)
    with pytest.raises(OSError, match="disk full"):
        restart.save(path, scene, params, s0, [], t0=0.0, t_end=1.0, n_out=1, next_out=0, chunk=5, dt=None)
    after = restart.load(path)
    np.testing.assert_array_equal(np.asarray(after["state"].x), np.asarray(before["state"].x))
    assert [p.name for p in tmp_path.iterdir()] == ["run.restart.h5"]  # no temporary file left


def test_an_existing_restart_file_is_never_overwritten_silently(small, tmp_path):
    """simulate(restart_file=p) refuses a p that exists (a saved run one could resume) and leaves
    it byte for byte as it was; overwrite=True replaces it."""
    scene, params, s0 = small
    path = tmp_path / "run.restart.h5"
    jaxmpm.simulate(scene, params, s0, t_end=0.5, n_out=1, progress=False, restart_file=str(path))
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="run.restart.h5 exists: refusing to overwrite it"):
        jaxmpm.simulate(scene, params, s0, t_end=0.25, n_out=1, progress=False, restart_file=str(path))
    assert path.read_bytes() == before
    jaxmpm.simulate(scene, params, s0, t_end=0.25, n_out=1, progress=False, restart_file=str(path), overwrite=True)
    assert restart.load(path)["t_end"] == 0.25


def test_restart_every_validated(small, tmp_path):
    scene, params, s0 = small
    with pytest.raises(ValueError, match=r"restart_every = 0 is invalid: allowed an integer >= 1"):
        jaxmpm.simulate(scene, params, s0, progress=False, restart_file=str(tmp_path / "r.h5"), restart_every=0)


def test_cli_resume_completes_an_interrupted_run(tmp_path, monkeypatch, capsys):
    from jaxmpm import cli, io

    out = tmp_path / "run"
    real = restart.save
    calls = {"n": 0}

    def save_then_stop(*a, **k):  # Ctrl-C after the third save
        real(*a, **k)
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(restart, "save", save_then_stop)
    argv = [
        "run",
        "--t-end",
        "1.5",
        "--n-out",
        "3",
        "--opt",
        "resolution=0.25",
        "--out",
        str(out),
        "--no-progress",
        "--x64",
        "--restart-every",
        "2",
    ]
    capsys.readouterr()
    assert cli.main(argv) == 130
    err = capsys.readouterr().err
    assert f"interrupted: its progress is saved in {out / 'elastic_impact.restart.h5'}" in err
    assert f"jaxmpm run --resume {out}" in err and "Traceback" not in err
    monkeypatch.setattr(restart, "save", real)
    assert not (out / "elastic_impact.h5").exists()
    assert cli.main(argv) == 2  # the same command again: it points to --resume, not --overwrite alone
    err = capsys.readouterr().err
    assert f"continue an interrupted run with `jaxmpm run --resume {out}`" in err and "discards it" in err
    assert (
        cli.main(["run", "--resume", str(out / "elastic_impact.restart.h5"), "--no-progress"]) == 0
    )  # the file, named
    _, history = io.read(out / "elastic_impact.h5")
    scene = dataclasses.replace(jaxmpm.load_scene("elastic_impact", resolution=0.25), t_end=1.5, n_out=3)
    params = jaxmpm.default_params(scene)
    chunk = restart.load(out / "elastic_impact.restart.h5")["chunk"]
    _, full = jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), progress=False, chunk=chunk)
    np.testing.assert_array_equal(np.asarray(history.x), np.asarray(full.x))
    assert cli.main(["run", "--resume", str(out), "--no-progress"]) == 2  # complete: nothing to resume
    assert "is complete (t_end = 1.5 s reached, 3 outputs): nothing to resume" in capsys.readouterr().err
    assert cli.main(["run", "--resume", str(tmp_path), "--no-progress"]) == 2  # no restart file there
    assert "expected one *.restart.h5" in capsys.readouterr().err
    assert cli.main(["run", "--resume", str(tmp_path / "nowhere"), "--no-progress"]) == 2
    assert f"--resume '{tmp_path / 'nowhere'}' does not exist" in capsys.readouterr().err


# ----------------------------------------------------------------------------------- bad restart files
def _saved(small, path, **driver):
    """A restart file of the initial state, saved without running (fast)."""
    scene, params, s0 = small
    kw = dict(t0=0.0, t_end=1.5, n_out=3, next_out=0, chunk=5, dt=None)
    kw.update(driver)
    restart.save(path, scene, params, s0, [s0] * (kw["next_out"] + 1), **kw)
    return path


def _leaf(tree, name):
    """Index of the leaf `name` (e.g. ".v") in tree's flattening: the restart file's dataset number."""
    import jax

    return next(
        i for i, (k, _) in enumerate(jax.tree_util.tree_flatten_with_path(tree)[0]) if jax.tree_util.keystr(k) == name
    )


def test_load_names_a_file_that_is_not_a_restart_file(small, tmp_path):
    """Text, truncated, an output file of jaxmpm.io.write, a missing file: the path in the error."""
    from jaxmpm import io

    scene, params, s0 = small
    good = _saved(small, tmp_path / "good.restart.h5")
    text = tmp_path / "notes.restart.h5"
    text.write_text("not HDF5\n")
    cut = tmp_path / "cut.restart.h5"
    cut.write_bytes(good.read_bytes()[:3000])
    out, _ = io.write(tmp_path / "out.h5", scene, s0)
    for bad, what in (
        (text, "is not a readable HDF5 file"),
        (cut, "is not a readable HDF5 file"),
        (out, "is a jaxmpm output file, not a restart file"),
    ):
        for fn in (restart.load, restart.dtype):
            with pytest.raises(ValueError, match=what) as e:
                fn(bad)
            assert str(bad) in str(e.value)
    with pytest.raises(FileNotFoundError, match="missing.restart.h5 does not exist"):
        restart.load(tmp_path / "missing.restart.h5")
    assert restart.dtype(good) == np.asarray(s0.x).dtype


@pytest.mark.parametrize(
    "edit, what",
    [
        (lambda f: f.attrs.__delitem__("t0"), "it has no attribute 't0'"),
        (lambda f: f.__delitem__("history"), "it has no group /history"),
        (lambda f: f.__delitem__("scene"), "it has no /scene dataset"),
        (lambda f: f["state"].__delitem__("0003"), r"it has no dataset /state/0003 \(state.mass\)"),
        (lambda f: f["history"].move("0000", "0007"), r"/history holds \['0007'\]"),
    ],
)
def test_load_names_what_is_missing(small, tmp_path, edit, what):
    path = _saved(small, tmp_path / "r.restart.h5")
    with h5py.File(path, "r+") as f:
        edit(f)
    with pytest.raises(ValueError, match=what) as e:
        restart.load(path)
    assert str(path) in str(e.value)


def test_load_checks_shapes_and_dtypes_against_the_scene(small, tmp_path):
    scene, params, s0 = small
    path = _saved(small, tmp_path / "r.restart.h5")
    iv = _leaf(s0, ".v")
    with h5py.File(path, "r+") as f:
        del f[f"state/{iv:04d}"]
        f[f"state/{iv:04d}"] = np.zeros(3)
    with pytest.raises(ValueError, match=rf"r.restart.h5:/state/{iv:04d} \(state.v\) has shape \(3,\)"):
        restart.load(path)
    path = _saved(small, tmp_path / "i.restart.h5")
    with h5py.File(path, "r+") as f:
        d = f[f"history/0000/{iv:04d}"]
        v = d[()].astype(np.int32)
        del f[f"history/0000/{iv:04d}"]
        f[f"history/0000/{iv:04d}"] = v
    with pytest.raises(ValueError, match=rf"/history/0000/{iv:04d} \(state.v\) has shape .* and dtype int32"):
        restart.load(path)
    # the scene text edited to a larger body: the saved state has fewer particles than it samples
    path = _saved(small, tmp_path / "s.restart.h5")
    finer = jaxmpm.load_scene("elastic_impact", resolution=0.5)
    n, n_fine = s0.x.shape[0], jaxmpm.model.state.phase_slices(finer)[-1].stop
    with h5py.File(path, "r+") as f:
        del f["scene"]
        f["scene"] = jaxmpm.scene_to_toml(finer)
    with pytest.raises(ValueError, match=rf"\(state.x\) has shape \({n}, 2\) .*needs shape \({n_fine}, 2\)"):
        restart.resume(path, progress=False)


def test_load_checks_params_and_state_values(small, tmp_path):
    scene, params, s0 = small
    path = _saved(small, tmp_path / "e.restart.h5")
    iE = _leaf(params, ".phases['disk_a']['E']")
    with h5py.File(path, "r+") as f:
        f[f"params/{iE:04d}"][()] = -1.0
    with pytest.raises(ValueError, match=r"e.restart.h5:/params: params.phases\['disk_a'\]\['E'\] = -1.0 is invalid"):
        restart.load(path)
    path = _saved(small, tmp_path / "v.restart.h5")
    iv = _leaf(s0, ".v")
    with h5py.File(path, "r+") as f:
        v = f[f"state/{iv:04d}"][()]
        v[0, 0] = np.nan
        f[f"state/{iv:04d}"][()] = v
    with pytest.raises(ValueError, match=r"v.restart.h5:/state: state.v of particle 0 .* is not finite"):
        restart.load(path)


@pytest.mark.parametrize(
    "name, value, allowed",
    [
        ("t_end", np.nan, "a finite time > t0"),
        ("t_end", -1.0, "a finite time > t0"),
        ("t0", np.inf, "a finite time"),
        ("next_out", 5, r"an integer in \[0, n_out = 3\]"),
        ("next_out", -1, r"an integer in \[0"),
        ("chunk", 0, "an integer >= 1"),
        ("chunk", 2.5, "an integer"),
        ("n_out", 0, "an integer >= 1"),
        ("dt", -1.0, "a finite time step > 0 s, or NaN"),
        ("t_end", "soon", "a number"),
    ],
)
def test_load_checks_the_driver_attributes(small, tmp_path, name, value, allowed):
    """Today's failures: t_end = nan or next_out > n_out 'finished' at t = 0; chunk = 0 stalled."""
    path = _saved(small, tmp_path / "r.restart.h5")
    with h5py.File(path, "r+") as f:
        f.attrs[name] = value
    with pytest.raises(ValueError, match=rf"r.restart.h5: attribute {name} = .* is invalid: allowed {allowed}"):
        restart.resume(path, progress=False)


def test_load_checks_the_history_and_the_time(small, tmp_path):
    scene, params, s0 = small
    path = _saved(small, tmp_path / "h.restart.h5")
    with h5py.File(path, "r+") as f:
        f.attrs["next_out"] = 2
    with pytest.raises(ValueError, match="/history holds 1 states: attribute next_out = 2 needs 3"):
        restart.load(path)
    path = _saved(small, tmp_path / "t.restart.h5", t0=0.5)
    with pytest.raises(ValueError, match=r"state.t = 0.0 s lies outside the run \[t0, t_end\] = \[0.5, 1.5\] s"):
        restart.load(path)
    with pytest.raises(ValueError, match="restart_every = -1 is invalid"):
        restart.resume(path, progress=False, restart_every=-1)


def test_a_float64_restart_file_needs_64_bit_jax(small, tmp_path):
    import jax

    if np.asarray(small[2].x).dtype != np.float64:
        pytest.skip("needs a float64 run (jax_enable_x64, as in conftest.py)")
    path = _saved(small, tmp_path / "r.restart.h5")
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match="r.restart.h5 holds float64 arrays: enable 64-bit JAX"):
            restart.load(path)
    assert restart.load(path)["state"].x.dtype == np.float64
