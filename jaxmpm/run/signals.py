"""Signals during a host-driven run: `Interrupted` (a KeyboardInterrupt with the signal's number),
the handler that raises it, and the deferral of signals to the end of a chunk (`StopRequest`)."""

from __future__ import annotations

import signal
import threading
from types import FrameType
from typing import NoReturn


class Interrupted(KeyboardInterrupt):
    """A host-driven run stopped by a signal (SIGINT, or SIGTERM where `interrupt_on` handles it)
    after its current chunk, its restart file (if any) saved. signum: the signal's number."""

    def __init__(self, signum: int, message: str = ""):
        super().__init__(message or f"stopped by {signal.Signals(signum).name}")
        self.signum = signum


def interrupt_on(signum: int, frame: FrameType | None) -> NoReturn:
    """A signal handler that raises `Interrupted` (a KeyboardInterrupt), so that `finally` blocks
    clean up; `jaxmpm run` installs it for SIGTERM. While the host driver runs, it defers the
    signals handled by this or by Python's default SIGINT handler to the end of its chunk."""
    raise Interrupted(signum)


class StopRequest:
    """The signal received while the host driver defers them (signum; None: none). Between
    `install` and `restore` (on the main thread), SIGINT under Python's default handler, and
    SIGINT or SIGTERM under `interrupt_on`, only record it: the driver checks it between chunks,
    saves and raises `Interrupted`. (A KeyboardInterrupt raised at any bytecode could land in a
    weakref callback, where Python prints it and carries on: a lost Ctrl-C; or cut a save short.)
    A second signal stops at once: the handlers as before, Interrupted raised."""

    def __init__(self):
        self.signum = None
        self.previous = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            h = signal.getsignal(sig)
            if h is interrupt_on or (sig == signal.SIGINT and h is signal.default_int_handler):
                self.previous[sig] = h
                signal.signal(sig, self.handler)

    def handler(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            self.restore()
            raise Interrupted(signum, "stopped at once by a second signal: the restart file holds its last save")
        self.signum = signum

    def restore(self) -> None:
        for sig, h in self.previous.items():
            signal.signal(sig, h)
        self.previous = {}
