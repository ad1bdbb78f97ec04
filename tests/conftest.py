"""Verification runs in float64 (tests about float32 switch dtype explicitly)."""
import os

os.environ.setdefault("MPLBACKEND", "Agg")
# XLA's CPU backend at LLVM optimisation level 0: most of the suite's time is compilation, and
# level 0 compiles faster (test_hard_cases.py: 1:50 against 2:22). It changes how fast the code
# runs, not what it computes (IEEE arithmetic at every level). JAXMPM_TEST_XLA_OPT=default keeps
# XLA's default level; the benchmarks always run at it.
if os.environ.get("JAXMPM_TEST_XLA_OPT", "0") != "default":
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()

import jax

jax.config.update("jax_enable_x64", True)
