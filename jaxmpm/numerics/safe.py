"""Division guarded against empty nodes, with finite gradients on both branches."""

from __future__ import annotations

import jax.numpy as jnp


def safe_div(a, b, bmin):
    """a / b where b > bmin, else 0, with finite gradients on both branches (double where)."""
    ok = b > bmin
    return jnp.where(ok, a / jnp.where(ok, b, 1.0), 0.0)
