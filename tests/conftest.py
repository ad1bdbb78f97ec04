"""Verification runs in float64 (tests about float32 switch dtype explicitly)."""
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax

jax.config.update("jax_enable_x64", True)
