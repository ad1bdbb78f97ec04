"""The benchmarks never replace a user's file: outside benchmarks/results an existing output is
refused (exit status 2) before anything is measured, unless --overwrite."""

import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))

import outputs  # noqa: E402  benchmarks/outputs.py


def test_an_existing_file_outside_results_is_refused_unless_overwrite(tmp_path, capsys):
    mine = tmp_path / "mine.csv"
    mine.write_text("keep")
    with pytest.raises(SystemExit) as e:
        outputs.check_outputs(tmp_path / "new" / "a.csv", mine)
    assert e.value.code == 2 and f"{mine} exists: refusing to overwrite it" in capsys.readouterr().err
    outputs.check_outputs(mine, overwrite=True)
    outputs.check_outputs(outputs.RESULTS / "throughput.csv")  # the project's tables: rewritten freely
    outputs.check_outputs(tmp_path / "new" / "a.csv")
    assert (tmp_path / "new").is_dir() and mine.read_text() == "keep"
    with pytest.raises(SystemExit):
        outputs.check_outputs(tmp_path, overwrite=True)  # a folder is never a file


def test_replot_refuses_a_missing_table_and_keeps_an_existing_figure(tmp_path):
    table = tmp_path / "mine.csv"
    table.write_text((BENCH / "results" / "throughput.csv").read_text())
    (tmp_path / "mine.png").write_text("keep")
    run = lambda *a: subprocess.run(
        [sys.executable, str(BENCH / "throughput.py"), *a], capture_output=True, text=True, timeout=120
    )
    r = run("--replot", str(table))
    assert r.returncode == 2 and "mine.png exists" in r.stderr and (tmp_path / "mine.png").read_text() == "keep"
    r = run("--replot", str(tmp_path / "missing.csv"))
    assert r.returncode == 2 and "allowed an existing .csv table" in r.stderr and "Traceback" not in r.stderr


def test_compile_time_refuses_a_users_table_and_unknown_scenes_before_measuring(tmp_path):
    (tmp_path / "compile_time.csv").write_text("keep")
    run = lambda *a: subprocess.run(
        [sys.executable, str(BENCH / "compile_time.py"), *a], capture_output=True, text=True, timeout=120
    )
    r = run("--out", str(tmp_path), "--scenes", "vibrating_bar")
    assert (
        r.returncode == 2
        and "compile_time.csv exists" in r.stderr
        and (tmp_path / "compile_time.csv").read_text() == "keep"
    )
    r = run("--out", str(tmp_path / "new"), "--scenes", "no_such_scene")
    assert r.returncode == 2 and "no_such_scene" in r.stderr and not (tmp_path / "new").exists()
