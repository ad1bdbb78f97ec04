"""What a gradient costs on each built-in scene: forward time and value-and-gradient time of N steps
with every step checkpointed (`simulate(..., checkpoint="steps")`; --checkpoint times other
checkpointings beside it), their ratio and the gradient program's memory.

Each scene at its built-in defaults (the debris cloud coarse, resolution 0.75, with two velocity
fields as in grad_cost.py and with one), float64, a fixed time step of half the initial CFL step,
from step 100 of its run (so that the material has moved and, in the impacts, met). Loss: a weighted mean of the particles' final
position along axis 0 and velocity along the last axis (weights m_p (0.5 .. 1.5 over the particle
index), so that no symmetry of the scene zeroes it), a function of a scale a of the initial
velocities (the gradient d loss / d a flows through every stage of every step). Times: the
fastest of --rounds interleaved runs of the compiled programs (the forward, then the gradient);
the ratio is the gradient's fastest over the forward's fastest and, in brackets, the median of
the ratios within a round.

Prints a table, writes benchmarks/results/grad_by_scene.csv.

    python benchmarks/grad_by_scene.py [--steps 20] [--rounds 7] [--scenes elastic_impact,debris_cloud,...]
                                       [--checkpoint steps,none]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import statistics
import time

import jax

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py

jax.config.update("jax_enable_x64", True)

# label -> (built-in scene, its options)
SCENES = {
    "elastic_impact": ("elastic_impact", {}),
    "vibrating_bar": ("vibrating_bar", {}),
    "self_weight_column": ("self_weight_column", {}),
    "mpm88": ("mpm88", {}),
    "debris_cloud": ("debris_cloud", dict(resolution=0.75, fields=2)),
    "debris_cloud_1_field": ("debris_cloud", dict(resolution=0.75, fields=1)),
    "taylor_bar": ("taylor_bar", {}),
    "taylor_brittle": ("taylor_brittle", {}),
}


def problem(name, n_steps, checkpoint="steps"):
    """(loss(a), a0, particles, fields, what the scene composes) of a built-in scene; checkpoint:
    `simulate`'s (False: none)."""
    import jax.numpy as jnp

    import jaxmpm
    from jaxmpm.step import cfl_time_step

    builtin, options = SCENES[name]
    scene = jaxmpm.load_scene(builtin, **options)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    dt = 0.5 * float(cfl_time_step(scene, params, state))
    t0 = float(state.t) + 100 * dt
    state, _ = jaxmpm.simulate(scene, params, state, t_end=t0, n_out=1, dt=dt, n_steps=100, progress=False)
    weight = state.mass * jnp.linspace(0.5, 1.5, state.mass.shape[0])

    def loss(a):
        final, _ = jaxmpm.simulate(
            scene,
            params,
            dataclasses.replace(state, v=a * state.v),
            t_end=t0 + n_steps * dt,
            n_out=1,
            dt=dt,
            n_steps=n_steps,
            checkpoint=checkpoint,
            progress=False,
        )
        return jnp.sum(weight * (final.x[:, 0] + 1e-6 * final.v[:, -1])) / jnp.sum(weight)

    what = f"{scene.shape}, {scene.transfer}" + (", axisymmetric" if scene.axisymmetric else "")
    return loss, jnp.asarray(1.0), state.x.shape[0], scene.n_fields, what


def measure(name, n_steps, rounds, modes=("steps",)):
    """One row per checkpointing in `modes` ("steps", "nested", "none"), their programs timed
    interleaved in each round."""
    import jaxmpm

    progs = {}
    for mode in modes:
        loss, a, n_particles, n_fields, what = problem(name, n_steps, False if mode == "none" else mode)
        fwd = jaxmpm.jit(loss).lower(a).compile()
        vg = jaxmpm.jit(jax.value_and_grad(loss)).lower(a).compile()
        jax.block_until_ready(fwd(a))
        value, grad = jax.block_until_ready(vg(a))
        progs[mode] = (fwd, vg, bool(jax.numpy.isfinite(value) and jax.numpy.isfinite(grad)), program_mib(vg))
    times = {mode: ([], []) for mode in modes}
    for _ in range(rounds):
        for mode, (fwd, vg, _, _) in progs.items():
            tf, tg = times[mode]
            t0 = time.perf_counter()
            jax.block_until_ready(fwd(a))
            tf.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            jax.block_until_ready(vg(a))
            tg.append(time.perf_counter() - t0)
    return [
        dict(
            scene=name,
            composition=what,
            fields=n_fields,
            particles=n_particles,
            steps=n_steps,
            checkpoint=mode,
            forward_ms_per_step=min(tf) / n_steps * 1e3,
            gradient_ms_per_step=min(tg) / n_steps * 1e3,
            ratio=min(tg) / min(tf),
            ratio_paired_median=statistics.median(g / f for f, g in zip(tf, tg)),
            gradient_program_mib=progs[mode][3],
            finite=progs[mode][2],
            device=describe(),
        )
        for mode, (tf, tg) in times.items()
    ]


def program_mib(compiled):
    """MiB of XLA's buffer assignment for a compiled program: arguments, outputs, temporaries."""
    m = compiled.memory_analysis()
    return (m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes) / 2**20


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--steps", type=int, default=20, help="checkpointed steps timed (after 100 untimed)")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved timing rounds")
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated: " + " | ".join(SCENES))
    ap.add_argument(
        "--checkpoint",
        default="steps",
        help="comma-separated checkpointings of simulate, timed interleaved: steps | nested | none (False)",
    )
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    add_overwrite(ap)
    args = ap.parse_args()
    check_outputs(os.path.join(args.out, "grad_by_scene.csv"), overwrite=args.overwrite)
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [n for n in names if n not in SCENES]
    if unknown:
        ap.error(f"--scenes: unknown {unknown}; allowed: {', '.join(SCENES)}")
    modes = [m.strip() for m in args.checkpoint.split(",") if m.strip()]
    bad = [m for m in modes if m not in ("steps", "nested", "none")]
    if bad or not modes:
        ap.error(f"--checkpoint: unknown {bad}; allowed: steps, nested, none")
    rows = []
    print(
        f"{'scene':24s} {'composition':30s} {'K':>2s} {'particles':>9s} {'checkpoint':>10s} {'fwd ms/step':>11s} "
        f"{'grad ms/step':>12s} {'grad MiB':>9s}  ratio (paired median)"
    )
    for name in names:
        for r in measure(name, args.steps, args.rounds, modes):
            rows.append(r)
            print(
                f"{name:24s} {r['composition']:30s} {r['fields']:2d} {r['particles']:9d} {r['checkpoint']:>10s} "
                f"{r['forward_ms_per_step']:11.3f} {r['gradient_ms_per_step']:12.3f} {r['gradient_program_mib']:9.1f}  "
                f"{r['ratio']:.2f} ({r['ratio_paired_median']:.2f})",
                flush=True,
            )
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "grad_by_scene.csv")
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print("wrote", path, "|", describe())


if __name__ == "__main__":
    main()
