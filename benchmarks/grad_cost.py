"""Cost of a gradient through N steps: forward time, value-and-gradient time and peak memory,
for each checkpointing of `simulate`: "nested" (two-level, memory ~ sqrt(N)), "steps" (each step
recomputed from its stored input state, memory ~ N states) and none (every step's intermediates).

Scene: the coarse debris cloud (resolution 0.75, two velocity fields, float64), a fixed time step
of half the initial CFL step and t_end = N dt (the scene's grid grows with t_end). Loss: the
mass-weighted mean axial position of the projectile at t_end, a function of theta = (log C_d,
log C_h); the gradient is d loss / d theta (reverse mode). Peak memory: XLA's buffer assignment of
the compiled program (arguments + outputs + temporaries of `CompiledMemoryStats`), deterministic
and the same on any machine of the backend; times: wall seconds of one run after compilation
(the fastest of up to 3, forward and gradient interleaved, while their gradients take < 10 s). Runs whose
program needs more than --max-gib are compiled (for their memory) but not run.

Prints a table, writes benchmarks/results/grad_cost.csv and grad_cost.png (log-log).

    python benchmarks/grad_cost.py [--steps 100,300,1000,3000,10000] [--modes nested,steps,none] [--max-gib 8]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import platform
import time

import jax

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py

jax.config.update("jax_enable_x64", True)


def problem(n_steps):
    import jax.numpy as jnp

    import jaxmpm
    from jaxmpm.step import cfl_time_step

    probe = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2)
    p0 = jaxmpm.default_params(probe)
    dt = 0.5 * float(cfl_time_step(probe, p0, jaxmpm.init_state(probe, p0)))
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2, t_end=n_steps * dt)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    sl = jaxmpm.model.state.phase_slices(scene)[0]

    def loss(theta, checkpoint):
        p = dataclasses.replace(params, drag=jnp.exp(theta[0]), c_h=jnp.exp(theta[1]))
        final, _ = jaxmpm.simulate(
            scene, p, state, t_end=scene.t_end, n_out=1, dt=dt, n_steps=n_steps, checkpoint=checkpoint
        )
        m = final.mass[sl]
        return jnp.sum(m * final.x[sl, 1]) / jnp.sum(m)

    return loss, state.x.shape[0], dt


def program_bytes(compiled):
    """Arguments + outputs + temporaries of XLA's buffer assignment (the CPU backend's
    peak_memory_in_bytes does not count the temporaries of loops)."""
    m = compiled.memory_analysis()
    return m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes


def measure(n_steps, mode, max_bytes):
    """One row: mode "nested", "steps" or "none" (simulate's checkpoint "nested", "steps", False)."""
    import jax.numpy as jnp

    import jaxmpm

    checkpoint = False if mode == "none" else mode
    loss, n_particles, dt = problem(n_steps)
    theta = jnp.log(jnp.array([1.0, 0.15]))
    fwd = jaxmpm.jit(lambda th: loss(th, checkpoint))
    vg = jaxmpm.jit(jax.value_and_grad(lambda th: loss(th, checkpoint)))
    t0 = time.perf_counter()
    c_fwd = fwd.lower(theta).compile()
    c_vg = vg.lower(theta).compile()
    compile_s = time.perf_counter() - t0
    mem_fwd, mem_vg = program_bytes(c_fwd), program_bytes(c_vg)
    row = dict(
        steps=n_steps,
        checkpoint=mode,
        particles=n_particles,
        dt=dt,
        compile_s=round(compile_s, 2),
        forward_peak_mib=mem_fwd / 2**20,
        gradient_peak_mib=mem_vg / 2**20,
        forward_s=float("nan"),
        gradient_s=float("nan"),
        ratio=float("nan"),
        finite=None,
        device=describe(),
    )
    if mem_vg > max_bytes:
        return row
    jax.block_until_ready(c_fwd(theta))  # warm
    fwd_s, grad_s = [], []
    while not grad_s or (len(grad_s) < 3 and sum(grad_s) < 10.0):  # fastest of 3 for short runs
        t0 = time.perf_counter()
        jax.block_until_ready(c_fwd(theta))
        fwd_s.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        value, grad = jax.block_until_ready(c_vg(theta))
        grad_s.append(time.perf_counter() - t0)
    row["forward_s"], row["gradient_s"] = min(fwd_s), min(grad_s)
    row["ratio"] = row["gradient_s"] / row["forward_s"]
    row["finite"] = bool(jnp.isfinite(value) and jnp.all(jnp.isfinite(grad)))
    return row


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ck, style in (("nested", "o-"), ("steps", "^-."), ("none", "s--")):
        rs = [r for r in rows if r["checkpoint"] == ck]
        if not rs:
            continue
        n = [r["steps"] for r in rs]
        label = {"nested": "nested checkpointing", "steps": "each step checkpointed", "none": "no checkpointing"}[ck]
        axes[0].loglog(n, [r["gradient_peak_mib"] for r in rs], style, label=f"gradient, {label}")
        axes[0].loglog(n, [r["forward_peak_mib"] for r in rs], style, alpha=0.4, label=f"forward, {label}")
        axes[1].loglog(n, [r["forward_s"] for r in rs], style, alpha=0.4, label=f"forward, {label}")
        axes[1].loglog(n, [r["gradient_s"] for r in rs], style, label=f"gradient, {label}")
    axes[0].set_xlabel("steps N")
    axes[0].set_ylabel("peak memory (MiB)")
    axes[0].legend(fontsize="small")
    axes[1].set_xlabel("steps N")
    axes[1].set_ylabel("wall time (s)")
    axes[1].legend(fontsize="small")
    fig.suptitle("gradient through N steps of the coarse debris cloud (2 fields, float64)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--steps", default="100,300,1000,3000,10000")
    ap.add_argument("--modes", default="nested,steps,none", help="checkpointing: nested, steps, none")
    ap.add_argument("--max-gib", type=float, default=8.0, help="run only programs needing less (GiB)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    add_overwrite(ap)
    args = ap.parse_args()
    check_outputs(*(os.path.join(args.out, f"grad_cost.{ext}") for ext in ("csv", "png")), overwrite=args.overwrite)
    steps = [int(s) for s in args.steps.split(",")]
    modes = args.modes.split(",")
    for m in modes:
        if m not in ("nested", "steps", "none"):
            raise SystemExit(f"--modes: {m!r} is invalid: allowed nested, steps, none")
    rows = []
    print(f"{describe()} ({platform.processor() or platform.machine()}, {os.cpu_count()} cores), jax {jax.__version__}")
    print(f"{'N':>6} {'ckpt':>7} {'fwd MiB':>9} {'grad MiB':>9} {'fwd s':>8} {'grad s':>8} {'ratio':>6}")
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "grad_cost.csv")
    for n in steps:
        for ck in modes:
            r = measure(n, ck, args.max_gib * 2**30)
            rows.append(r)
            print(
                f"{n:>6} {ck:>7} {r['forward_peak_mib']:>9.1f} {r['gradient_peak_mib']:>9.1f} "
                f"{r['forward_s']:>8.3f} {r['gradient_s']:>8.3f} {r['ratio']:>6.2f}",
                flush=True,
            )
            with open(path, "w", newline="") as f:  # rewritten after each row: a long run keeps what it measured
                w = csv.DictWriter(f, fieldnames=list(rows[0]))
                w.writeheader()
                w.writerows(rows)
    png = os.path.join(args.out, "grad_cost.png")
    plot(rows, png)
    print(f"wrote {path}\nwrote {png}")


if __name__ == "__main__":
    main()
