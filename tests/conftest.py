"""Verification runs in float64 (tests about float32 switch dtype explicitly)."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# XLA's CPU backend at LLVM optimisation level 0: most of the suite's time is compilation, and
# level 0 compiles faster (test_hard_cases.py: 1:50 against 2:22). It changes how fast the code
# runs, not what it computes (IEEE arithmetic at every level). JAXMPM_TEST_XLA_OPT=default keeps
# XLA's default level; the benchmarks always run at it.
if os.environ.get("JAXMPM_TEST_XLA_OPT", "0") != "default":
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()

# jaxmpm's commands run in the tests without the persistent compilation cache (no writes into the
# user's cache folder); tests/test_compile_cache.py turns it on in its own processes
os.environ.setdefault("JAXMPM_NO_CACHE", "1")

import jax

jax.config.update("jax_enable_x64", True)
# every mixing of dtypes in jaxmpm is written out (an astype, or a value of the array's own dtype):
# "strict" promotion makes an implicit one an error instead of a silent change of precision
jax.config.update("jax_numpy_dtype_promotion", "strict")
