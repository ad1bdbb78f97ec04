"""The progress bar of a fixed-length run, fed from inside the compiled scan."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
from jax.typing import ArrayLike
from tqdm.auto import tqdm

# The progress bar of the fixed-length run in flight (`fixed_fn` with report=True), fed by
# jax.debug.callback from inside the compiled scan: steps done, counted on the host.
_PROGRESS = {"bar": None}
REPORTS = 100  # progress updates per fixed-length run, at most


def report_steps(done: ArrayLike) -> None:
    bar = _PROGRESS["bar"]
    done = int(np.max(np.asarray(done)))  # the same count from every member or device
    if bar is None:
        return
    if not _PROGRESS.get("running"):  # the first report: compiling is over, the clock starts
        bar.reset(total=bar.total)
        bar.set_postfix_str("running")
        _PROGRESS["running"] = True
    if done > bar.n:
        bar.update(done - bar.n)


@contextlib.contextmanager
def progress_bar(total: int, desc: str, enabled: bool) -> Iterator[None]:
    """A tqdm bar of `total` steps that `fixed_fn(..., report=True)` advances while it runs."""
    if not enabled:
        yield
        return
    _PROGRESS["bar"] = tqdm(total=total, unit="step", desc=desc, postfix="compiling")
    _PROGRESS["running"] = False
    try:
        yield
    finally:
        _PROGRESS["bar"].close()
        _PROGRESS["bar"] = None
