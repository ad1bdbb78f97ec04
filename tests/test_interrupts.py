"""A run's robustness: saving costs what is new, one Ctrl-C or SIGTERM stops a run with its restart
file saved and no temporary file left, and a later run removes those a killed run left."""

import dataclasses
import os
import signal
import subprocess
import sys
import time
import warnings

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import jaxmpm  # noqa: E402
from jaxmpm import cli, restart  # noqa: E402

RUN = ["elastic_impact", "--opt", "resolution=0.25", "--no-progress"]


@pytest.fixture(autouse=True)
def default_signal_handling():
    """Each test starts with SIGINT and SIGTERM as a user's shell gives them to Python: SIGINT under
    Python's default handler and neither blocked. A test process (a parallel test worker) may
    inherit them ignored or blocked, and a child process inherits both: the run then never sees the
    signal. Restored afterwards."""
    handler = signal.getsignal(signal.SIGINT)
    blocked = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _small(t_end, n_out):
    scene = dataclasses.replace(jaxmpm.load_scene("elastic_impact", resolution=0.25), t_end=t_end, n_out=n_out)
    params = jaxmpm.default_params(scene)
    return scene, params, jaxmpm.init_state(scene, params)


def _written_bytes() -> int:
    """Bytes this process has passed to write calls (Linux /proc/self/io: wchar)."""
    with open("/proc/self/io") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("wchar:"))


@pytest.mark.skipif(not os.path.exists("/proc/self/io"), reason="needs Linux /proc/self/io")
def test_a_save_writes_what_is_new_not_the_history_again(tmp_path, monkeypatch):
    """The bytes each save of the restart file writes stay those of a state and an output or two,
    however many outputs came before (the whole file was rewritten at each save: quadratic)."""
    scene, params, s0 = _small(t_end=1.5, n_out=60)
    path = tmp_path / "run.restart.h5"
    real, sizes = restart.save, []

    def measured(*a, **k):
        before = _written_bytes()
        real(*a, **k)
        sizes.append(_written_bytes() - before)

    monkeypatch.setattr(restart, "save", measured)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # n_out <= the steps: no warning
        final, hist = jaxmpm.simulate(scene, params, s0, progress=False, restart_file=str(path), restart_every=1)
    state_bytes = sum(np.asarray(a).nbytes for a in jax.tree.leaves(s0))
    assert len(sizes) >= 60 and os.path.getsize(path) > 50 * state_bytes
    later = sizes[1:]
    assert max(later) < 4 * state_bytes, (max(later), state_bytes)  # one state and one output, with metadata
    assert max(sizes[-10:]) < 2 * max(sizes[1:11])  # as much at the end as at the start
    # and the file is the complete run: it loads with every output, and resumes to the same results
    saved = restart.load(path)
    assert saved["next_out"] == 60 and len(saved["history"]) == 61
    np.testing.assert_array_equal(np.asarray(saved["history"][-1].x), np.asarray(final.x))
    np.testing.assert_array_equal(np.asarray(saved["history"][30].x), np.asarray(hist.x[30]))


def test_more_outputs_than_steps_are_warned_about():
    scene, params, s0 = _small(t_end=0.05, n_out=50)
    steps = jaxmpm.plan_steps(scene, params, s0, 0.05, safety=1.0)
    assert steps < 50
    with pytest.warns(
        RuntimeWarning, match=rf"n_out = 50 exceeds the about {steps} steps of the run to t_end = 0.05 s"
    ):
        jaxmpm.simulate(scene, params, s0, progress=False)


def _start(out, *extra):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "jaxmpm", "run", *RUN, "--out", str(out), *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def _wait_for(path, proc, timeout=400.0):
    t0 = time.monotonic()
    while not path.exists():
        assert proc.poll() is None, f"the run ended before saving: {proc.communicate()}"
        assert time.monotonic() - t0 < timeout, f"no {path} after {timeout} s"
        time.sleep(0.05)


def _leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def test_one_ctrl_c_stops_a_run_of_many_outputs_and_leaves_a_resumable_restart_file(tmp_path):
    out = tmp_path / "run"
    rfile = out / "elastic_impact.restart.h5"
    proc = _start(out, "--t-end", "3", "--n-out", "150", "--restart-every", "1")
    try:
        _wait_for(rfile, proc)
        # into the outputs, saving after each: the run steps for only about 1.5 s after its first
        # save on an idle 2-core machine (a wait of 1 s let it finish before the signal there)
        time.sleep(0.25)
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
        stopped_after = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, stderr
    assert stopped_after < 10.0, stopped_after
    assert f"interrupted: its progress is saved in {rfile}" in stderr
    assert "Traceback" not in stderr and "Exception ignored" not in stderr
    assert _leftovers(out) == [] and not (out / "elastic_impact.h5").exists()
    saved = restart.load(rfile)
    assert 0 < saved["next_out"] < 150
    scene, params, final, history = restart.resume(rfile, progress=False, restart_every=0)
    assert float(final.t) == pytest.approx(3.0) and history.x.shape[0] == 151
    np.testing.assert_array_equal(
        np.asarray(history.x[: saved["next_out"] + 1]), np.stack([np.asarray(s.x) for s in saved["history"]])
    )


def test_sigterm_stops_a_run_leaving_no_temporary_file(tmp_path):
    out = tmp_path / "run"
    rfile = out / "elastic_impact.restart.h5"
    proc = _start(out, "--t-end", "3", "--n-out", "150", "--restart-every", "1")
    try:
        _wait_for(rfile, proc)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert f"terminated: its progress is saved in {rfile}" in stderr and "Traceback" not in stderr
    assert _leftovers(out) == [] and [p.name for p in out.iterdir()] == [rfile.name]
    assert 0 <= restart.load(rfile)["next_out"] < 150


def test_a_run_removes_the_temporary_files_killed_runs_left(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a process that no longer exists
    dead = out / f".elastic_impact.restart.h5.{gone.pid}-0123456789ab.tmp"
    old = out / ".elastic_impact.h5.0123456789ab.tmp"  # naming no process, an hour old
    recent = out / ".elastic_impact.h5.ba9876543210.tmp"  # naming no process, just written
    live = out / f".elastic_impact.restart.h5.{os.getpid()}-abcdefabcdef.tmp"  # a running process's
    for p in (dead, old, recent, live):
        p.write_bytes(b"partial")
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    (out / "elastic_impact.h5").write_bytes(b"an earlier output")  # so that the run stops before simulating
    assert cli.main(["run", *RUN, "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert f"removed 2 temporary files that earlier runs killed while writing left in {out}" in captured.out
    assert dead.name in captured.out and old.name in captured.out
    assert "elastic_impact.h5 exists: refusing to overwrite it" in captured.err
    assert sorted(_leftovers(out)) == sorted([recent.name, live.name])


def test_sigint_inside_simulate_stops_after_the_chunk_with_the_file_saved(tmp_path, monkeypatch):
    """In Python: a SIGINT that arrives during a save is deferred to the end of the chunk; then the
    run saves and raises Interrupted (a KeyboardInterrupt), and resuming gives the uninterrupted
    run's results bit for bit."""
    from jaxmpm.run.driver import Interrupted

    scene, params, s0 = _small(t_end=1.5, n_out=6)
    full, hist_full = jaxmpm.simulate(scene, params, s0, progress=False, chunk=7)
    path = tmp_path / "run.restart.h5"
    real, calls = restart.save, {"n": 0}

    def save_with_a_signal_inside(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            os.kill(os.getpid(), signal.SIGINT)  # handled while this save runs: deferred
        real(*a, **k)

    monkeypatch.setattr(restart, "save", save_with_a_signal_inside)
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(Interrupted, match=rf"stopped by SIGINT: its progress is saved in {path}"):
        jaxmpm.simulate(scene, params, s0, progress=False, chunk=7, restart_file=str(path), restart_every=1)
    assert signal.getsignal(signal.SIGINT) is handler  # the handler as before
    assert calls["n"] == 4  # the save it was in, and one on stopping
    monkeypatch.setattr(restart, "save", real)
    _, _, final, hist = restart.resume(path, progress=False)
    np.testing.assert_array_equal(np.asarray(final.x), np.asarray(full.x))
    np.testing.assert_array_equal(np.asarray(hist.x), np.asarray(hist_full.x))
