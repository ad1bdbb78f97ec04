"""Which form of the transfers and DDMP's corner sums a traced step takes: the CPU's or the GPU's.

The two forms compute the same values and derivatives (tests/test_transfer_forms.py); they differ
in how XLA runs them:
  "cpu"  loops over the stencil offsets and the cell corners (`transfer.gather_by_offset`, the
         windowed scatter of particle blocks, DDMP's slab loop in `ddmp.add_corners`): a scatter
         runs on one thread on XLA's CPU backend, and loops keep each pass vectorised.
  "gpu"  every stencil offset in one pass: the (N, S) node indices of each particle's stencil, one
         gather of N x S rows and one scatter-add of N x S updates (`transfer.scatter` / `gather`
         on a `shapes.Stencil`), and the corner sums as one fused sum of shifted copies. On a GPU a
         loop launches several small kernels per offset and reads the particle arrays once per
         offset; XLA's scatter there is atomic and parallel.

The form is read when a step is traced: `transfer_form()` is the one the context sets
(`transfer_forms`), else the environment variable JAXMPM_TRANSFER_FORM (auto | cpu | gpu), else
"auto": "cpu" where JAX's default backend is the CPU and "gpu" elsewhere. A function compiled
before the setting changed keeps the form it was traced with.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterator

import jax

ENV = "JAXMPM_TRANSFER_FORM"
FORMS = ("cpu", "gpu")
_FORCED = contextvars.ContextVar("jaxmpm_transfer_form", default=None)


def _checked(form, where):
    if form not in FORMS + ("auto",):
        raise ValueError(f"{where} = {form!r} is invalid: allowed auto | cpu | gpu")
    return form


def transfer_form() -> str:
    """ "cpu" or "gpu": the form of the transfers for the function being traced (see the module)."""
    form = _FORCED.get()
    if form is None:
        form = _checked(os.environ.get(ENV, "auto").strip().lower() or "auto", ENV)
    if form == "auto":
        return "cpu" if jax.default_backend() == "cpu" else "gpu"
    return form


@contextlib.contextmanager
def transfer_forms(form: str) -> Iterator[None]:
    """Within this context, steps traced take the given form ("auto", "cpu" or "gpu"), whatever
    the backend and the environment say: e.g. the GPU form traced and run on the CPU."""
    token = _FORCED.set(_checked(form, "transfer form"))
    try:
        yield
    finally:
        _FORCED.reset(token)
