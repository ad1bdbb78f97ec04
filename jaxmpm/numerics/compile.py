"""Compilation settings for jaxmpm's compiled functions: `jaxmpm.jit` is `jax.jit` with them.

On the CPU, XLA hands small contractions, reductions and even elementwise fusions to its YNNPACK
library, which is slow for the shapes of an MPM step (tiny per-particle and per-cell arrays):
measured in benchmarks/throughput.py, a DDMP step is about 2x and a three-field step 2.5x faster
with those fusions off. The option is passed per compiled function (`compiler_options`), so it
changes nothing else in the process, and only where this XLA knows it (checked once by compiling
a trivial function; an XLA without it simply compiles with its defaults). Set the environment
variable JAXMPM_XLA_DEFAULTS=1 to compile with XLA's defaults instead.

    run = jaxmpm.jit(lambda p, s: step(p, s))   # in user code: as fast as jaxmpm's own drivers

A function compiled by `jit` is traced with `native_reductions()` true: DDMP's corner contractions
and the stencil contractions (`bilinear_contraction`) then compute their tangents as reductions,
which reverse mode transposes to a broadcast (DDMP's gradients 1.6x faster than with the unrolled
form, which stays the forward form).
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import os
from collections.abc import Callable, Iterator
from typing import Any

import jax
import numpy as np

CPU_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": ""}  # empty: no YNNPACK fusions
# Which forms code traced now takes. A JAX user context: JAX keys its caches of traces, lowerings
# and executables on it (jit's, and those of checkpoint, custom_jvp, scan, keyed by function), so a
# trace made in one form is never reused in the other. With a plain context variable a reduction
# form traced inside `jit` (say, the step under jax.checkpoint) came back from those caches into a
# later eager jax.grad, compiled without CPU_OPTIONS, where YNNPACK's fusion of it crashes the
# process (a segmentation fault in the README's gradient example).
# A jax without user contexts compiles with XLA's defaults (`compiler_options`), so that no
# reduction form is ever traced for `jit`; native_reductions_forms then sets a context variable.
_USER_CONTEXTS = hasattr(jax, "make_user_context")
_NATIVE_REDUCTIONS = (
    jax.make_user_context(False)
    if _USER_CONTEXTS
    else contextvars.ContextVar("jaxmpm_native_reductions", default=False)
)


def native_reductions() -> bool:
    """Whether the function being traced will be compiled with CPU_OPTIONS (by `jit`), so that
    XLA compiles reductions itself. Read at trace time by code with two equivalent forms: a
    reduction (`jnp.sum` over a broadcast product, whose reverse mode is a broadcast) is the one
    to use then; elsewhere YNNPACK takes the reductions and is slow for these shapes, and unrolled
    sums of slices are used (their reverse mode is a padded copy per slice)."""
    return bool(_NATIVE_REDUCTIONS.value if _USER_CONTEXTS else _NATIVE_REDUCTIONS.get())


@contextlib.contextmanager
def native_reductions_forms(on: bool = True) -> Iterator[None]:
    """Within this context, code traced takes the forms of `native_reductions() == on`."""
    if _USER_CONTEXTS:
        with _NATIVE_REDUCTIONS(bool(on)):
            yield
        return
    token = _NATIVE_REDUCTIONS.set(bool(on))
    try:
        yield
    finally:
        _NATIVE_REDUCTIONS.reset(token)


def _traced_natively(fun):
    @functools.wraps(fun)
    def traced(*args, **kw):
        with native_reductions_forms(True):
            return fun(*args, **kw)

    return traced


def bilinear_contraction(
    unrolled: Callable[[jax.Array, jax.Array], jax.Array], reduced: Callable[[jax.Array, jax.Array], jax.Array]
) -> Callable[[jax.Array, jax.Array], jax.Array]:
    """A bilinear contraction f(x, A) of tiny per-particle or per-cell arrays with its value by
    `unrolled` (sums of slices: the fastest forward) and its tangent by `reduced` (a reduction over
    a broadcast product) when traced for `jit`: reverse mode transposes the tangent, and a
    reduction transposes to a broadcast where the unrolled form transposes to a padded copy of the
    other argument per slice (DDMP's gradients 1.7x slower). Under a plain jax.jit, where YNNPACK
    would take the reductions, both are unrolled."""

    @jax.custom_jvp
    def f(x, A):
        return unrolled(x, A)

    @f.defjvp
    def f_jvp(primals, tangents):
        (x, A), (dx, dA) = primals, tangents
        contraction = reduced if native_reductions() else unrolled
        # the value through f itself: where this rule is applied inside a linearisation that the
        # step evaluates (the continuity form's jax.vjp), an outer derivative then meets f again
        # and takes this tangent, not the transpose of the unrolled sums (a padded copy per slice)
        return f(x, A), contraction(dx, A) + contraction(x, dA)

    return f


@functools.lru_cache(maxsize=1)
def compiler_options() -> dict | None:
    """The options jaxmpm compiles with: CPU_OPTIONS, or None where this XLA does not know them
    or the user opted out with JAXMPM_XLA_DEFAULTS=1, or this jax has no user contexts to key its
    caches on the contraction forms (`native_reductions`)."""
    if os.environ.get("JAXMPM_XLA_DEFAULTS", "") == "1" or not _USER_CONTEXTS:
        return None
    try:
        jax.jit(lambda x: x + 1, compiler_options=CPU_OPTIONS).lower(np.float32(0.0)).compile()
    except Exception:  # an XLA without the option (or a jax without compiler_options)
        return None
    return dict(CPU_OPTIONS)


def jit(fun: Callable | None = None, **kwargs: Any) -> Callable:
    """`jax.jit(fun, **kwargs)` with jaxmpm's compiler options; usable as a decorator.
    XLA takes compiler options only for a top-level computation: called with tracers (inside
    another jit, whose options then apply to the whole, or under an eager grad or vmap, which
    stage the call), the function runs as a plain `jax.jit`. So wrap the outermost function:
    `jaxmpm.jit(jax.grad(loss))`, not `jax.grad(loss)` of a function that calls this one."""
    if fun is None:
        return functools.partial(jit, **kwargs)
    plain = jax.jit(fun, **kwargs)
    opts = compiler_options()
    if opts is None:
        return plain
    fast = jax.jit(
        _traced_natively(fun), **{**kwargs, "compiler_options": {**opts, **kwargs.get("compiler_options", {})}}
    )

    @functools.wraps(fun)
    def call(*args, **kw):
        # called with tracers (inside jit, grad or vmap) the call is staged into a jaxpr, where
        # XLA refuses compiler options ("only ... top-level jax.jit"): a plain jax.jit then. (It
        # used to try the options first and fall back on that error, which traced the function,
        # and under grad linearized it, twice: the debris cloud's gradient traced for 12 s, now 6.5)
        if any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves((args, kw))):
            return plain(*args, **kw)
        return fast(*args, **kw)

    call.lower = fast.lower
    call.plain = plain
    return call
