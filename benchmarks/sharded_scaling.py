"""Time per step of one simulation with its particles split across 1, 2, ... devices (jaxmpm.distributed).

Each device scatters its particles into the whole grid, the nodal arrays are summed across the
devices (psum) and the grid update is repeated on each. On the CPU, the devices are XLA host
devices (`--host-devices N` sets XLA_FLAGS=--xla_force_host_platform_device_count=N before JAX
starts): they share the machine's cores, so this measures the overhead of the split rather than a
speed-up; on a machine with several GPUs it measures the scaling. Fixed dt, float32 unless --x64;
interleaved repeats, fastest and median. Writes benchmarks/results/sharded_scaling_<scene>.csv.

    python benchmarks/sharded_scaling.py [--scene mpm88|debris_cloud] [--dim 2|3] [--host-devices 2] [--steps 100]

(--dim 3: the peers' 3D scene, mpm88 at 64^3; writes sharded_scaling_mpm88_3d.csv.)
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import statistics
import sys
import time

from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--scene", default="mpm88", choices=("mpm88", "debris_cloud"))
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2, help="mpm88 only: 2D (128^2) or 3D (64^3)")
    ap.add_argument("--host-devices", type=int, default=2, help="CPU only: XLA host devices to create (default 2)")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--x64", action="store_true")
    ap.add_argument("--out", default=None, help="CSV path (default benchmarks/results/sharded_scaling_<scene>.csv)")
    add_overwrite(ap)
    args = ap.parse_args()
    if args.out is None:
        suffix = "_3d" if args.dim == 3 else ""
        args.out = os.path.join(os.path.dirname(__file__), "results", f"sharded_scaling_{args.scene}{suffix}.csv")
    check_outputs(args.out, overwrite=args.overwrite)
    if args.dim == 3 and args.scene != "mpm88":
        raise SystemExit(f"--dim 3 is invalid with --scene {args.scene}: allowed with mpm88 only")
    if "jax" in sys.modules:
        raise SystemExit("run this script on its own: the device count is fixed when JAX starts")
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={args.host_devices}"
    ).strip()

    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", bool(args.x64))
    import jaxmpm
    from jaxmpm import distributed

    scene = jaxmpm.load_scene(
        args.scene,
        **(
            {"resolution": 1.0, "fields": 2}
            if args.scene == "debris_cloud"
            else {"dim": args.dim, "n_grid": 128 if args.dim == 2 else 64}
        ),
    )
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    dt = 0.5 * float(jaxmpm.step.cfl_time_step(scene, params, state))
    devices = jax.devices()
    counts = [k for k in (1, 2, 4, 8, 16) if k <= len(devices)]
    runs = {}
    for k in counts:
        mesh = None if k == 1 else distributed.particle_mesh(devices[:k])
        s0 = state if mesh is None else distributed.to_shards(scene, state, mesh)
        step = jaxmpm.make_step(scene) if mesh is None else distributed.make_sharded_step(scene, mesh)
        run = jaxmpm.jit(
            lambda p, s, step=step: jax.lax.scan(
                lambda c, _: (step(p, c, jnp.inf, dt), None), s, None, length=args.steps
            )[0]
        )
        t0 = time.perf_counter()
        jax.block_until_ready(run(params, s0))
        runs[k] = (run, s0, time.perf_counter() - t0)
    times = {k: [] for k in counts}
    for _ in range(args.repeats):  # interleaved
        for k in counts:
            run, s0, _ = runs[k]
            t0 = time.perf_counter()
            jax.block_until_ready(run(params, s0))
            times[k].append(time.perf_counter() - t0)
    n = state.x.shape[0]
    rows = []
    print(
        f"{scene.name}: {n} particles, {scene.grid.n_nodes} nodes x {scene.n_fields} field(s), {args.steps} steps, "
        f"{'float64' if args.x64 else 'float32'}, devices: {devices[0].platform} x {len(devices)}"
    )
    print(f"{'devices':>8} {'ms/step (fastest)':>18} {'median':>8} {'x 1 device':>11} {'compile s':>10}")
    base = min(times[1]) / args.steps
    for k in counts:
        fast, med = min(times[k]) / args.steps, statistics.median(times[k]) / args.steps
        rows.append(
            dict(
                scene=scene.name,
                devices=k,
                platform=devices[0].platform,
                particles=n,
                steps=args.steps,
                ms_per_step=1e3 * fast,
                ms_per_step_median=1e3 * med,
                speedup=base / fast,
                compile_s=runs[k][2],
                dtype="float64" if args.x64 else "float32",
                cpus=os.cpu_count(),
                jax=jax.__version__,
                python=platform.python_version(),
            )
        )
        print(f"{k:>8} {1e3 * fast:>18.3f} {1e3 * med:>8.3f} {base / fast:>11.2f} {runs[k][2]:>10.1f}")
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print("wrote", args.out)


if __name__ == "__main__":
    main()
