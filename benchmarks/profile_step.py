"""Where the time of a step and of its gradient goes, stage by stage.

A `jax.profiler` trace of the forward run and of its gradient; every XLA kernel's time is put on
the stage of the step it belongs to (`jaxmpm.step.STAGES`: the step runs each stage, and the grid
update's and grid-to-particle stage's parts, under a `jax.named_scope`, which XLA keeps in each
operation's metadata) and, in the gradient, on its pass:
  forward pass  the run itself, storing each step's input state (checkpoint="steps");
  recompute     each step evaluated again in reverse, from its stored state;
  transpose     the step's derivative transposed (reverse mode proper).
Control-flow kernels (while loops, conditionals, calls) are not counted themselves: the kernels
they run are. An operation under two parts' names counts in the first of STAGE_PARTS: the
continuity form's volume rate (E7), built with the interface forces and evaluated with the
velocity gradient, shows as 4_grid_to_particle/interface_force.

The problem is grad_by_scene.py's: a built-in scene at its defaults, float64, N checkpointed steps
from step 100, d loss / d a for a scale a of the initial velocities. Each kernel's trace event
costs time, so a run under the profiler takes longer than without it, most for programs of many
small kernels; read the table's shares and ratios, and the untraced times printed above it. Each
cell is the fastest of --runs calls (the machine's load lengthens some of them).

    python benchmarks/profile_step.py [--scene elastic_impact] [--steps 20] [--runs 5] [--parts]

Prints the table; writes benchmarks/results/profile_<scene>.csv (ms per step under the profiler).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import csv
import glob
import gzip
import json
import os
import re
import tempfile
import time

import jax

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py
from grad_by_scene import SCENES, problem
from jaxmpm.step import STAGE_PARTS, STAGES

jax.config.update("jax_enable_x64", True)

CONTROL_FLOW = ("while", "conditional", "call", "async-start", "async-done")
PASSES = ("forward pass", "recompute", "transpose")
OUTSIDE = "outside the stages"
_INSTRUCTION = re.compile(r"\s*(?:ROOT )?%?([\w.\-]+) = [^=]*? ([\w\-]+)\(.*?metadata=\{op_name=\"([^\"]*)\"")


def kernel_names(hlo_text):
    """{HLO instruction name: op_name} of the compiled module's operations, control flow left out."""
    names = {}
    for line in hlo_text.splitlines():
        m = _INSTRUCTION.match(line)
        if m and m.group(2) not in CONTROL_FLOW:
            names[m.group(1)] = m.group(3)
    return names


def stage_of(op_name, parts):
    """The stage (and with parts=True the part within it) an operation's op_name names."""
    stage = next((s for s in STAGES if f"/{s}/" in f"/{op_name}/"), None)
    if stage is None:
        return OUTSIDE
    part = next((p for p in STAGE_PARTS if f"/{p}/" in f"/{op_name}/"), None) if parts else None
    return stage if part is None else f"{stage}/{part}"


def pass_of(op_name):
    """The gradient's pass an operation belongs to (`PASSES`)."""
    if "transpose(" not in op_name:
        return PASSES[0]
    return PASSES[1] if "rematted_computation" in op_name else PASSES[2]


def kernel_times(compiled, args, runs):
    """[{HLO instruction name: microseconds}] of each of `runs` calls, from one profiler trace
    (a kernel belongs to the call that started last before it)."""
    for _ in range(2):
        jax.block_until_ready(compiled(*args))
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d, create_perfetto_trace=True):
            for _ in range(runs):
                jax.block_until_ready(compiled(*args))
        trace = json.load(gzip.open(glob.glob(os.path.join(d, "**", "*.trace.json.gz"), recursive=True)[0]))
    events = [
        e for e in (trace["traceEvents"] if isinstance(trace, dict) else trace) if e.get("ph") == "X" and "dur" in e
    ]
    calls = sorted(e["ts"] for e in events if e.get("name", "").startswith("PjitFunction"))[-runs:]
    per_call = [collections.Counter() for _ in calls]
    for e in events:
        i = bisect.bisect_right(calls, e["ts"]) - 1
        if i >= 0:
            per_call[i][e.get("name", "")] += e["dur"]
    return per_call


def wall_seconds(compiled, args, rounds=5):
    """Fastest of `rounds` untraced calls, s."""
    best = float("inf")
    for _ in range(rounds):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def profile(name, n_steps, runs, parts):
    """Rows {stage, forward_ms, <pass>_ms..., gradient_ms, ratio} in ms per step under the profiler,
    and the untraced wall times (s) of the forward run and of the gradient."""
    import jaxmpm

    loss, a, *_ = problem(name, n_steps)
    programs = {
        "forward": jaxmpm.jit(loss).lower(a).compile(),
        "gradient": jaxmpm.jit(jax.value_and_grad(loss)).lower(a).compile(),
    }
    wall = {k: wall_seconds(c, (a,)) for k, c in programs.items()}
    table = collections.defaultdict(dict)  # stage -> column -> the fastest call's ms per step
    for kind, compiled in programs.items():
        names = kernel_names(compiled.as_text())
        calls = kernel_times(compiled, (a,), runs)
        if len(calls) < runs:
            raise RuntimeError(f"the profiler's trace shows {len(calls)} calls of {runs}: no PjitFunction events")
        for times in calls:
            cells = collections.Counter()
            for kernel, us in times.items():
                if kernel in names:
                    op = names[kernel]
                    cells[stage_of(op, parts), "forward" if kind == "forward" else pass_of(op)] += us / n_steps / 1e3
            for (stage, column), ms in cells.items():
                table[stage][column] = min(ms, table[stage].get(column, float("inf")))
    rows = []
    for stage in sorted(table, key=lambda s: (s == OUTSIDE, s)):
        c = collections.Counter(table[stage])
        grad = sum(c[p] for p in PASSES)
        rows.append(
            dict(
                scene=name,
                stage=stage,
                forward_ms=c["forward"],
                **{p.replace(" ", "_") + "_ms": c[p] for p in PASSES},
                gradient_ms=grad,
                ratio=grad / c["forward"] if c["forward"] > 0 else float("nan"),
            )
        )
    total = {k: sum(r[k] for r in rows) for k in rows[0] if k.endswith("_ms")}
    rows.append(dict(scene=name, stage="all", **total, ratio=total["gradient_ms"] / total["forward_ms"]))
    return rows, wall


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--scene", default="elastic_impact", help=" | ".join(SCENES))
    ap.add_argument("--steps", type=int, default=20, help="checkpointed steps (after 100 untimed)")
    ap.add_argument(
        "--runs", type=int, default=5, help="calls of each program under the profiler (each cell: the fastest)"
    )
    ap.add_argument(
        "--parts", action="store_true", help="split the grid update and the grid-to-particle stage into their parts"
    )
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    add_overwrite(ap)
    args = ap.parse_args()
    if args.scene not in SCENES:
        ap.error(f"--scene: unknown {args.scene!r}; allowed: {', '.join(SCENES)}")
    check_outputs(os.path.join(args.out, f"profile_{args.scene}.csv"), overwrite=args.overwrite)
    if args.steps < 1 or args.runs < 1:
        ap.error("--steps and --runs: at least 1")
    rows, wall = profile(args.scene, args.steps, args.runs, args.parts)
    print(
        f"{args.scene}, {args.steps} checkpointed steps, float64, {describe()}; untraced: forward "
        f"{wall['forward'] / args.steps * 1e3:.3f} ms per step, gradient {wall['gradient'] / args.steps * 1e3:.3f} "
        f"({wall['gradient'] / wall['forward']:.2f} forward runs)"
    )
    print("ms per step under the profiler:")
    print(
        f"{'stage':40s} {'forward':>8s} {'share':>6s} | {'fwd pass':>8s} {'recompute':>9s} {'transpose':>9s} {'gradient':>8s} {'ratio':>6s}"
    )
    whole = rows[-1]["forward_ms"]
    for r in rows:
        print(
            f"{r['stage']:40s} {r['forward_ms']:8.3f} {r['forward_ms'] / whole:6.1%} | {r['forward_pass_ms']:8.3f} "
            f"{r['recompute_ms']:9.3f} {r['transpose_ms']:9.3f} {r['gradient_ms']:8.3f} {r['ratio']:6.2f}"
        )
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, f"profile_{args.scene}.csv")
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) + ["device"])
        w.writeheader()
        w.writerows(dict(r, device=describe()) for r in rows)
    print("wrote", path)


if __name__ == "__main__":
    main()
