"""JAX's persistent compilation cache for jaxmpm's commands: a second run of the same scene (or a
second calibration start) reads its compiled programs back from disk instead of compiling them.

The folder is $JAXMPM_CACHE_DIR if set, else jaxmpm/xla under the user's cache folder
($XDG_CACHE_HOME, else ~/.cache). The `jaxmpm run` command and `python -m calibration` turn it on
(`enable`); JAXMPM_NO_CACHE=1 or their --no-cache flag leave it off. Library use is unchanged:
call `enable()` from a script to opt in. A cached program is keyed by JAX on the program, the
compile options, the backend and the versions of jax and jaxlib, so a changed step or an upgrade
compiles afresh; the folder may be deleted at any time.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import jax

ENV_OFF = "JAXMPM_NO_CACHE"
ENV_DIR = "JAXMPM_CACHE_DIR"
ENV_MIN = "JAXMPM_CACHE_MIN_COMPILE_S"
MIN_COMPILE_S = 0.5  # programs that compile faster than this are not written (jax's default: 1 s)


def cache_dir() -> Path:
    """The folder of the persistent compilation cache (see the module docstring)."""
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jaxmpm" / "xla"


def disabled_by_environment() -> bool:
    """Whether JAXMPM_NO_CACHE asks for no cache (any value but empty, 0, false or no)."""
    return os.environ.get(ENV_OFF, "").strip().lower() not in ("", "0", "false", "no")


def enable(path: str | os.PathLike | None = None) -> Path | None:
    """Turn JAX's persistent compilation cache on at `path` (default `cache_dir()`), unless
    JAXMPM_NO_CACHE is set. Call it before the first compilation of the process. Returns the
    folder, or None where the cache stays off (asked, or the folder cannot be created: a warning)."""
    if disabled_by_environment():
        return None
    folder = Path(path).expanduser() if path is not None else cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        warnings.warn(
            f"compilation cache off: cannot create {folder} ({e.strerror or e}); set {ENV_DIR} to a "
            f"writable folder, or {ENV_OFF}=1",
            stacklevel=2,
        )
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_seconds())
    return folder


def min_compile_seconds() -> float:
    """Programs that compile faster than this (s) are not written: JAXMPM_CACHE_MIN_COMPILE_S, else
    MIN_COMPILE_S. A value that is not a number >= 0 is refused naming the variable."""
    text = os.environ.get(ENV_MIN, "").strip()
    if not text:
        return MIN_COMPILE_S
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise ValueError(f"{ENV_MIN} = {text!r} is invalid: allowed a number of seconds >= 0")
    return value
