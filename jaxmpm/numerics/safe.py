"""Division guarded against empty nodes, with finite gradients on both branches."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike


def safe_div(a: ArrayLike, b: jax.Array, bmin: ArrayLike) -> jax.Array:
    """a / b where b > bmin, else 0, with finite gradients on both branches (double where)."""
    ok = b > bmin
    return jnp.where(ok, a / jnp.where(ok, b, 1.0), 0.0)
