"""The persistent compilation cache (jaxmpm/compile_cache.py): a second `jaxmpm run` of the same
scene reads its compiled programs back instead of compiling them, and the cache stays off where
asked."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from jaxmpm import compile_cache

ROOT = Path(__file__).resolve().parent.parent
TINY = ["--t-end", "0.05", "--n-out", "2", "--set", "grid.cells=[16,16]", "--set", "grid.h=0.0625", "--no-progress"]
HIT = "Persistent compilation cache hit for"


def _run(tmp_path, out, cache, *extra, **env_extra):
    """`python -m jaxmpm run` of the tiny elastic impact in a fresh process, the cache folder given
    by JAXMPM_CACHE_DIR and JAX's compile log on (it names every persistent-cache hit)."""
    env = {k: v for k, v in os.environ.items() if k != compile_cache.ENV_OFF}
    env.update(JAXMPM_CACHE_DIR=str(cache), JAX_LOG_COMPILES="1", PYTHONPATH=str(ROOT), **env_extra)
    p = subprocess.run(
        [sys.executable, "-m", "jaxmpm", "run", "--out", str(tmp_path / out), *TINY, *extra],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=600,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    return p.stderr


def _entries(folder):
    return sorted(p.name for p in Path(folder).iterdir()) if Path(folder).is_dir() else []


def test_a_second_run_reads_the_compiled_step_back(tmp_path):
    """Every program is written (threshold 0 s: which programs pass the default threshold depends
    on the machine's load, so the two runs could write different sets), and the second run reads
    each back and writes none."""
    cache = tmp_path / "cache"
    first = _run(tmp_path, "a", cache, **{compile_cache.ENV_MIN: "0"})
    written = _entries(cache)
    assert written, "the first run wrote nothing into the cache folder"
    assert HIT not in first
    second = _run(tmp_path, "b", cache, **{compile_cache.ENV_MIN: "0"})
    hits = [line for line in second.splitlines() if HIT in line]
    assert len(hits) >= len(written), (written, hits)  # every program the first run wrote is read back
    assert _entries(cache) == written  # and none compiled afresh and written
    assert (tmp_path / "b").is_dir()


@pytest.mark.slow
@pytest.mark.parametrize("how", ["flag", "environment"])
def test_the_cache_stays_off_where_asked(tmp_path, how):
    cache = tmp_path / "cache"
    if how == "flag":
        log = _run(tmp_path, "a", cache, "--no-cache")
    else:
        log = _run(tmp_path, "a", cache, **{compile_cache.ENV_OFF: "1"})
    assert _entries(cache) == [] and HIT not in log


def test_cache_folder_and_switch(monkeypatch, tmp_path):
    monkeypatch.delenv(compile_cache.ENV_DIR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert compile_cache.cache_dir() == tmp_path / "xdg" / "jaxmpm" / "xla"
    monkeypatch.setenv(compile_cache.ENV_DIR, str(tmp_path / "mine"))
    assert compile_cache.cache_dir() == tmp_path / "mine"
    for value, off in (("1", True), ("yes", True), ("0", False), ("", False)):
        monkeypatch.setenv(compile_cache.ENV_OFF, value)
        assert compile_cache.disabled_by_environment() is off
    monkeypatch.setenv(compile_cache.ENV_OFF, "1")
    assert compile_cache.enable(tmp_path / "never") is None and not (tmp_path / "never").exists()
    monkeypatch.setenv(compile_cache.ENV_MIN, "0.25")
    assert compile_cache.min_compile_seconds() == 0.25
    for bad in ("-1", "soon", "nan"):
        monkeypatch.setenv(compile_cache.ENV_MIN, bad)
        with pytest.raises(ValueError, match=compile_cache.ENV_MIN):
            compile_cache.min_compile_seconds()
