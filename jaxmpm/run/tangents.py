"""Tangents given ahead of time, so that JAX linearizes a scan over steps once.

`lax.scan`'s linearization iterates to a fixpoint over which carries have nonzero tangents: a
state whose fields get their tangents only from a first step makes JAX linearize the scan's body
twice (benchmarks/NOTES.md, Tracing). `evolving_tangents` gives them before the scan.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero

from jaxmpm.model.state import State


# State fields whose tangent a step never changes: mass (constant) and, with a given dt, t
# (t + dt: its tangent is that of t and dt, and marking it would give every step a tangent of dt)
def _unmarked(fixed_dt: bool) -> tuple[str, ...]:
    return ("mass", "t") if fixed_dt else ("mass",)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def evolving_tangents(fixed_dt: bool, state: State, inputs: Any) -> State:
    """state itself. Its JVP gives every field that a step gives a tangent (all but `_unmarked`)
    one already, depending on the nonzero tangents of (state, inputs) (its own tangent plus a zero
    selected against a sum of those), where JAX would know it to be zero until a first step had made it
    nonzero. A scan over the steps then starts with the tangents its steps produce, so that JAX
    linearizes its body once, not twice (its fixpoint over which carries have tangents; the step
    in simulate's two nested scans (outputs, steps) was linearized four times). Values, derivatives and the
    compiled program are unchanged (but for that zero, once per run); only tracing is shorter."""
    return state


def _evolving_tangents_jvp(fixed_dt, primals, tangents):
    state, _ = primals
    dstate = tangents[0]
    nonzero = [
        jnp.asarray(t)
        for t in jax.tree.leaves(tangents, is_leaf=lambda t: isinstance(t, SymbolicZero))
        if not isinstance(t, SymbolicZero)
    ]
    nonzero = [t for t in nonzero if jnp.issubdtype(t.dtype, jnp.inexact)]
    if not nonzero:
        return state, dstate
    # zero, but a tangent (it depends on the nonzero ones): selected, not multiplied by 0, so
    # that an infinite tangent or cotangent (float32 adjoints can overflow) gives 0, not NaN
    nil = sum(
        jax.lax.select(jnp.asarray(False), jnp.sum(t).real, jnp.zeros((), jnp.sum(t).real.dtype)) for t in nonzero
    )
    keep = _unmarked(fixed_dt)

    def marked(name, value, dvalue):
        if value is None or name in keep:
            return dvalue
        base = jnp.zeros_like(value) if isinstance(dvalue, SymbolicZero) else dvalue
        return base + nil.astype(value.dtype)

    return state, dataclasses.replace(
        dstate,
        **{f.name: marked(f.name, getattr(state, f.name), getattr(dstate, f.name)) for f in dataclasses.fields(state)},
    )


evolving_tangents.defjvp(_evolving_tangents_jvp, symbolic_zeros=True)
