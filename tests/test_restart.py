"""Restart files: a resumed run is bit-identical to an uninterrupted one; an interrupted write
leaves the previous restart file readable."""
import dataclasses
import os

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
    assert [p.name for p in tmp_path.iterdir()] == ["run.restart.h5"]      # no temporary file left


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

    class Stop(Exception):
        pass

    def save_then_stop(*a, **k):
        real(*a, **k)
        calls["n"] += 1
        if calls["n"] == 3:
            raise Stop

    monkeypatch.setattr(restart, "save", save_then_stop)
    with pytest.raises(Stop):
        cli.main(["run", "--t-end", "1.5", "--n-out", "3", "--opt", "resolution=0.25", "--out", str(out),
                  "--no-progress", "--x64", "--restart-every", "2"])
    monkeypatch.setattr(restart, "save", real)
    assert not (out / "elastic_impact.h5").exists()
    assert cli.main(["run", "--resume", str(out), "--no-progress"]) == 0
    _, history = io.read(out / "elastic_impact.h5")
    scene = dataclasses.replace(jaxmpm.load_scene("elastic_impact", resolution=0.25), t_end=1.5, n_out=3)
    params = jaxmpm.default_params(scene)
    chunk = restart.load(out / "elastic_impact.restart.h5")["chunk"]
    _, full = jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), progress=False, chunk=chunk)
    np.testing.assert_array_equal(np.asarray(history.x), np.asarray(full.x))
    assert cli.main(["run", "--resume", str(tmp_path), "--no-progress"]) == 2     # no restart file there
    assert "expected one *.restart.h5" in capsys.readouterr().err
