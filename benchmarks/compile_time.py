"""Time to the first answer: how long a fresh process waits before a run or a gradient returns.

A compiled program is fast (grad_by_scene.py), but its first call traces the step in Python,
transforms it (for a gradient: linearizes and transposes the checkpointed scan), lowers it and
compiles it with XLA. This benchmark measures each part, for the forward run and the
value-and-gradient of grad_by_scene.py's problem (a built-in scene, float64, N checkpointed steps
from step 100, d loss / d a for a scale a of the initial velocities):
  trace   tracing, AD transformations and lowering to StableHLO (Python; never cached on disk)
  compile XLA's compilation of the lowered program
  first   the first call of the compiled program
  run     the fastest of 3 further calls
Each scene is measured in fresh processes (nothing cached in memory), with JAX's persistent
compilation cache off, then on with an empty cache folder ("cold": compiled and written), then
again on the same folder ("warm": the compiled programs read back).

Prints a table, writes benchmarks/results/compile_time.csv.

    python benchmarks/compile_time.py [--steps 20] [--scenes elastic_impact,debris_cloud,...]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time

from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py

CACHES = ("off", "cold", "warm")
DEFAULT_SCENES = "elastic_impact,taylor_bar,debris_cloud_1_field,debris_cloud"


def measure_in_this_process(name, n_steps):
    """{program: {trace, compile, first, run}} in s for the forward run and the gradient."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import jaxmpm
    from grad_by_scene import problem

    loss, a, *_ = problem(name, n_steps)
    out = {}
    for program, f in (("forward", loss), ("gradient", jax.value_and_grad(loss))):
        t0 = time.perf_counter()
        lowered = jaxmpm.jit(f).lower(a)
        t1 = time.perf_counter()
        compiled = lowered.compile()
        t2 = time.perf_counter()
        jax.block_until_ready(compiled(a))
        t3 = time.perf_counter()
        runs = []
        for _ in range(3):
            s = time.perf_counter()
            jax.block_until_ready(compiled(a))
            runs.append(time.perf_counter() - s)
        out[program] = dict(trace=t1 - t0, compile=t2 - t1, first=t3 - t2, run=min(runs))
    return out


def measure(name, n_steps, cache, cache_dir):
    """The measurement in a fresh Python process (`cache`: 'off', or the persistent cache's folder)."""
    env = dict(os.environ)
    code = (
        "import json, sys; sys.path.insert(0, {here!r}); import jax; "
        "{setup}"
        "from compile_time import measure_in_this_process; "
        "print('RESULT', json.dumps(measure_in_this_process({name!r}, {n})))"
    )
    setup = (
        ""
        if cache == "off"
        else (
            f"jax.config.update('jax_compilation_cache_dir', {cache_dir!r}); "
            "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0); "
        )
    )
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            code.format(here=os.path.dirname(os.path.abspath(__file__)), setup=setup, name=name, n=n_steps),
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("RESULT ")]
    if r.returncode != 0 or not lines:
        raise RuntimeError(f"{name} ({cache}): the measuring process failed:\n{r.stderr[-3000:]}")
    return json.loads(lines[-1][len("RESULT ") :])


def main():
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from devices import describe  # benchmarks/devices.py
    from grad_by_scene import SCENES

    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--steps", type=int, default=20, help="checkpointed steps of the programs (after 100 untimed)")
    ap.add_argument("--scenes", default=DEFAULT_SCENES, help="comma-separated: " + " | ".join(SCENES))
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    add_overwrite(ap)
    args = ap.parse_args()
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [n for n in names if n not in SCENES]
    if unknown or not names:
        ap.error(f"--scenes: unknown {unknown}; allowed: {', '.join(SCENES)}")
    if args.steps < 1:
        ap.error("--steps: at least 1")
    path = os.path.join(args.out, "compile_time.csv")
    check_outputs(path, overwrite=args.overwrite)
    rows = []
    print(
        f"{'scene':22s} {'program':9s} {'cache':5s} {'trace s':>8s} {'compile s':>9s} {'first s':>8s} "
        f"{'to answer s':>11s} {'run s':>7s}"
    )
    for name in names:
        with tempfile.TemporaryDirectory() as cache_dir:
            for cache in CACHES:
                result = measure(name, args.steps, cache, cache_dir)
                for program, t in result.items():
                    total = t["trace"] + t["compile"] + t["first"]
                    rows.append(
                        dict(
                            scene=name,
                            program=program,
                            cache=cache,
                            steps=args.steps,
                            trace_s=t["trace"],
                            compile_s=t["compile"],
                            first_call_s=t["first"],
                            to_answer_s=total,
                            run_s=t["run"],
                            device=describe(),
                        )
                    )
                    print(
                        f"{name:22s} {program:9s} {cache:5s} {t['trace']:8.2f} {t['compile']:9.2f} {t['first']:8.3f} "
                        f"{total:11.2f} {t['run']:7.3f}",
                        flush=True,
                    )
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print("wrote", path, "|", describe())


if __name__ == "__main__":
    main()
