"""Throughput of jaxmpm against the peer MLS-MPM scripts, in particle-steps per second.

What it measures: Mpart-steps/s = particles * steps / seconds / 1e6 on the peers' 'mpm88' scene
(weakly compressible fluid block falling in a box, quadratic B-spline APIC, slip walls 3 nodes
thick, gravity; /work/shared/bench/peers/scene.py), float32, fixed time step
dt = 2e-4 * 128 / n_grid (2D) or 2e-4 * 64 / n_grid (3D), as the peers use.

Rows:
  jax-naive, taichi, warp   the peer scripts in ../shared/bench/peers/, run unchanged as subprocesses
                            (`python <peer>.py n_grid dim scale steps`, one JSON line each); Taichi and
                            Warp only where importable in this interpreter, else "not installed".
                            Each peer compiles/warms up, then times one run; we take the median over
                            --repeats separate calls. jax-naive+ynn is the same script with the XLA flag.
  jaxmpm                    jaxmpm.load_scene("mpm88"): `lax.scan` of `step(params, state, dt=dt)` for
                            `steps` steps, compiled with `jaxmpm.jit` (XLA's YNNPACK fusions off on the
                            CPU: jaxmpm/compile.py), compiled ahead (compile_s), warmed up once from the
                            initial state, then the median of --repeats timed runs, each continuing
                            from the previous one (the peers also time steps after the warm-up).
  jaxmpm-split-cores        the same with the particles split across the CPU's cores, one XLA host device
                            per core (XLA_FLAGS=--xla_force_host_platform_device_count=<CPUs>;
                            `jaxmpm.distributed`: each device scatters its particles, the nodal sums
                            are added across the devices, the grid update is repeated on each). XLA
                            runs a scatter on one thread, so on one device it leaves the other cores
                            idle for the step's largest part; the peers' Taichi and Warp use every core.
  jaxmpm-xla-defaults       the same compiled with XLA's default options (JAXMPM_XLA_DEFAULTS=1).
  jaxmpm-linear/-ddmp-musl  the same particles with shape 'linear' / 'ddmp' and the default musl update.
  ...-cpuform / -gpuform    the same with the transfers traced in the CPU's or the GPU's form
                            (JAXMPM_TRANSFER_FORM=cpu | gpu; jaxmpm/forms.py), whatever the backend:
                            before and after of the GPU forms in one run. The rows without the
                            suffix take the backend's form.
  taichi-cuda, warp-cuda    the Taichi and Warp peers on the GPU (their fifth argument 'cuda'); only
                            where JAX's default backend is a GPU, or named in --configs.
--ppc P sets jaxmpm's lattice to P particles per cell per axis and runs the peers with the same
number of particles (their ppc_scale argument = jaxmpm's count / their default count), in the same
box: equal particle counts per row. Without it each side keeps its own default count. --timeout S
limits each configuration's process (a row that runs past it says so); the table is rewritten
after every row, so a run stopped early keeps the rows it finished.
A run is "stable" when, after all (1 + repeats) * steps steps (2D defaults: t = 0.4 s; the block hits
the floor at ~0.16 s), every state value is finite, all particles are in the grid, max |v| < 10 m/s
(free fall from the block's top gives ~3.3 m/s, the splash ~7 m/s) and the total energy (kinetic +
gravitational + internal) has grown by less than 1% (the fluid should only lose energy). A jaxmpm row
that is not stable at the peers' dt is re-run at 0.3 * jaxmpm.cfl_limit(...) and says so in its note.
Note: jaxmpm samples particles on a regular lattice (2 per cell per axis in 2D: ~10.6k particles),
the peers 8192 random ones; the per-particle-step rate makes the two comparable.

Every configuration runs in its own subprocess (this script with a hidden `--one NAME`), so compile
caches, memory and XLA_FLAGS do not leak between them; they run one after another.

Run:  python benchmarks/throughput.py                  # 2D, 128^2 grid, 500 steps
      python benchmarks/throughput.py --dim 3          # 3D, 64^3 grid, 100 steps
      python benchmarks/throughput.py --only jaxmpm --steps 200 --repeats 5
      python benchmarks/throughput.py --dim 3 --n-grid 128 --configs jaxmpm,jax-naive   # the issue's GPU size
      python benchmarks/throughput.py --replot benchmarks/results/throughput.csv   # PNG of a table
A jaxmpm row also gives the kernels of its compiled run and the kernels it launches per step
(benchmarks/kernel_count.py on the compiled rollout's HLO).
Writes benchmarks/results/throughput.csv (2D) or throughput_3d.csv (3D; or --out) with device, CPU
count, jax version and date, and a bar chart of the rates beside it (same name, .png).
On a GPU (JAX's default backend) the CPU-only configurations are left out unless --configs names
them; the peer scripts then run there too where they can (jax-naive on JAX's default backend).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import importlib.metadata
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs, check_table  # benchmarks/outputs.py

HERE = Path(__file__).resolve().parent
PEERS_DIR = HERE.parent.parent / "shared" / "bench" / "peers"  # /work/shared/bench/peers
YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type="

CORES = os.cpu_count() or 1
HOST_DEVICES_FLAG = f"--xla_force_host_platform_device_count={CORES}"
# jaxmpm configurations: name -> (shape, transfer, extra XLA flag or None)
JAXMPM = {
    "jaxmpm": ("bspline2", "apic", None),
    "jaxmpm-split-cores": ("bspline2", "apic", HOST_DEVICES_FLAG),
    "jaxmpm-xla-defaults": ("bspline2", "apic", "JAXMPM_XLA_DEFAULTS=1"),
    "jaxmpm-linear-musl": ("linear", "musl", None),
    "jaxmpm-ddmp-musl": ("ddmp", "musl", None),
    "jaxmpm-apic-cpuform": ("bspline2", "apic", "JAXMPM_TRANSFER_FORM=cpu"),
    "jaxmpm-apic-gpuform": ("bspline2", "apic", "JAXMPM_TRANSFER_FORM=gpu"),
    "jaxmpm-ddmp-musl-cpuform": ("ddmp", "musl", "JAXMPM_TRANSFER_FORM=cpu"),
    "jaxmpm-ddmp-musl-gpuform": ("ddmp", "musl", "JAXMPM_TRANSFER_FORM=gpu"),
}
# peer configurations: name -> (script, module it needs, extra XLA flag or None, dims it covers, device argument)
PEERS = {
    "jax-naive": ("jax_mpm.py", "jax", None, (2, 3), None),  # on JAX's default backend (a GPU where there is one)
    "jax-naive+ynn": ("jax_mpm.py", "jax", YNN_FLAG, (2, 3), None),
    "taichi-cpu": ("taichi_mpm.py", "taichi", None, (2, 3), None),
    "warp-cpu": ("warp_mpm.py", "warp", None, (2,), None),
    "taichi-cuda": ("taichi_mpm.py", "taichi", None, (2, 3), "cuda"),
    "warp-cuda": ("warp_mpm.py", "warp", None, (2,), "cuda"),
}
# configurations that measure the CPU alone: left out by default where JAX's default backend is a GPU
CPU_ONLY = ("jax-naive+ynn", "taichi-cpu", "warp-cpu", "jaxmpm-split-cores", "jaxmpm-xla-defaults")
# configurations that need a GPU: left out by default where JAX's default backend is the CPU
GPU_ONLY = ("taichi-cuda", "warp-cuda")
FIELDS = [
    "config",
    "dim",
    "n_grid",
    "particles",
    "steps",
    "dt",
    "seconds",
    "compile_s",
    "mpart_steps_per_s",
    "ratio_to_jax_naive",
    "kernels",
    "launches_per_step",
    "finite",
    "stable",
    "note",
    "xla_flags",
    "device",
    "cpu_count",
    "jax_version",
    "date",
]


def peer_dt(dim: int, n_grid: int) -> float:
    """The peers' fixed time step (scene.py), s."""
    return 2e-4 * 128 / n_grid if dim == 2 else 2e-4 * 64 / n_grid


def peer_particles(dim: int, n_grid: int) -> int:
    """The peers' default particle count (scene.py: 8192 in 2D, n_grid^3 / 4 in 3D)."""
    return 8192 if dim == 2 else 8 * n_grid**3 // 32


def mpm88_scene(n_grid: int, dim: int, ppc: int | None):
    """jaxmpm's mpm88 scene, with ppc particles per cell per axis on its lattice if given."""
    import dataclasses

    import jaxmpm

    if ppc is None:
        return jaxmpm.load_scene("mpm88", n_grid=n_grid, dim=dim)
    scene = jaxmpm.load_scene("mpm88", n_grid=n_grid, dim=dim, ppc_scale=1e-9)  # its own lattice: 1 per cell, replaced
    if ppc is not None:
        scene = dataclasses.replace(scene, phases=(dataclasses.replace(scene.phases[0], ppc=ppc),))
    return scene


def child_env(flag: str | None) -> dict:
    """Environment of a child process: XLA_FLAGS extended with `flag` (read when jax is imported),
    or, for a flag NAME=VALUE, that variable set."""
    env = dict(os.environ)
    if flag and not flag.startswith("--"):
        name, value = flag.split("=", 1)
        env[name] = value
    elif flag:
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + flag).strip()
    return env


# ----------------------------------------------------------------------------- child: one jaxmpm run
def run_jaxmpm(name: str, dim: int, n_grid: int, steps: int, repeats: int, ppc: int | None = None) -> dict:
    import dataclasses

    import jax  # imported here, after the parent has set XLA_FLAGS in our environment
    import jax.numpy as jnp
    import numpy as np

    import jaxmpm

    from jaxmpm import distributed

    shape, transfer, flag = JAXMPM[name]
    from jaxmpm.numerics.forms import transfer_form

    scene = dataclasses.replace(mpm88_scene(n_grid, dim, ppc), shape=shape, transfer=transfer)
    params = jaxmpm.default_params(scene)  # float32 (x64 stays off)
    state0 = jaxmpm.init_state(scene, params)
    n = int(state0.n_particles)
    shards = len(jax.devices()) if flag == HOST_DEVICES_FLAG else 1
    if shards > 1:  # particles split across the devices (padding copies carry eps^2 of the mass)
        mesh = distributed.particle_mesh()
        state0 = distributed.to_shards(scene, state0, mesh)
        step = distributed.make_sharded_step(scene, mesh)
    else:
        step = jaxmpm.make_step(scene)

    def rollout(params, state, dt):
        return jax.lax.scan(lambda s, _: (step(params, s, jnp.inf, dt), None), state, None, length=steps)[0]

    def energy(s):  # kinetic + gravitational + internal (state.energy is per unit mass), J
        m = s.mass
        return float(jnp.sum(m * (0.5 * jnp.sum(s.v**2, -1) - s.x @ params.gravity + s.energy)))

    e0 = energy(state0)  # (padding copies: eps^2 of a particle's energy each)

    def stability(s):  # -> (finite, stable, max |v| m/s, relative energy change)
        s = distributed.from_shards(scene, s, shards) if shards > 1 else s
        finite = all(bool(np.isfinite(np.asarray(a)).all()) for a in jax.tree.leaves(s))
        if not finite:
            return False, False, float("nan"), float("nan")
        x, vmax = np.asarray(s.x), float(jnp.max(jnp.linalg.norm(s.v, axis=-1)))
        inside = bool(((x >= np.asarray(scene.grid.origin)) & (x <= np.asarray(scene.grid.hi))).all())
        de = (energy(s) - e0) / abs(e0)
        return True, inside and vmax < 10.0 and de < 0.01, vmax, de

    def measure(dt):
        """Warm-up run from the initial state, then `repeats` timed runs, each continuing from the last
        (as the peers time their second block of steps); returns the final state and the run times."""
        s = jax.block_until_ready(sim(params, state0, dt))
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            s = jax.block_until_ready(sim(params, s, dt))
            times.append(time.perf_counter() - t0)
        return s, times

    dt = jnp.asarray(peer_dt(dim, n_grid), jnp.float32)
    t0 = time.perf_counter()
    sim = jaxmpm.jit(rollout).lower(params, state0, dt).compile()  # dt is traced: no recompile on fallback
    compile_s = time.perf_counter() - t0
    from kernel_count import count_kernels  # benchmarks/kernel_count.py

    try:
        counts = count_kernels(sim.as_text())
        counts = dict(kernels=counts["kernels"], launches_per_step=round(counts["launches"] / steps, 1))
    except Exception as e:  # a count is a bonus: never lose the row for it
        counts = dict(kernels=None, launches_per_step=None, count_error=repr(e)[:100])
    out, times = measure(dt)
    finite, stable, vmax, de = stability(out)
    note = "dt = peers' dt"
    if not stable:  # fall back to a CFL-bounded step, and say so
        why = f"max|v| = {vmax:.3g} m/s, dE/E0 = {de:+.2%}" if finite else "non-finite"
        note = f"UNSTABLE at peers' dt ({why} at t = {float(out.t):.3g} s): re-run at 0.3 * cfl_limit"
        dt = jnp.asarray(0.3 * jaxmpm.cfl_limit(scene, params, jaxmpm.init_state(scene, params)), jnp.float32)
        out, times = measure(dt)
        finite, stable, vmax, de = stability(out)
        note += "" if stable else ", STILL UNSTABLE"
    note += f"; at t = {float(out.t):.3g} s: max|v| = {vmax:.3g} m/s, dE/E0 = {de:+.2%}; {transfer_form()} form"
    sec = statistics.median(times)
    if shards > 1:
        note += f"; particles split across {shards} host devices ({jax.devices()[0].platform})"
    return (
        dict(
            config=name,
            dim=dim,
            n_grid=n_grid,
            particles=n,
            steps=steps,
            dt=float(f"{float(dt):.6g}"),
            seconds=sec,
            compile_s=compile_s,
            mpart_steps_per_s=n * steps / sec / 1e6,
            finite=finite,
            stable=stable,
            note=note + f"; runs {', '.join('%.3f' % t for t in times)} s",
            device=describe(),
            jax_version=jax.__version__,
        )
        | counts
    )


# ----------------------------------------------------------------------------- parent: run everything
def default_backend() -> str:
    """JAX's default backend ("cpu", "gpu", ...), asked of a child process: the parent keeps no
    device (a GPU client would hold memory the children need)."""
    p = subprocess.run(
        [sys.executable, "-c", "import jax; print(jax.default_backend())"], capture_output=True, text=True
    )
    return p.stdout.strip().splitlines()[-1] if p.returncode == 0 and p.stdout.strip() else "cpu"


def run_child(cmd: list[str], env: dict, cwd: Path, timeout: float = 900) -> dict:
    """Run one subprocess and parse the last line of its stdout as JSON; errors become a note."""
    try:
        p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return dict(note=f"timed out after {timeout:.0f} s")
    lines = p.stdout.strip().splitlines()
    if p.returncode != 0 or not lines:
        err = (p.stderr.strip().splitlines() or ["no output"])[-1]
        return dict(note=f"failed (rc {p.returncode}): {err[:200]}")
    return json.loads(lines[-1])


def run_peer(name: str, a) -> dict:
    script, module, flag, dims, device = PEERS[name]
    row = dict(config=name, dim=a.dim, n_grid=a.n_grid, steps=a.steps, xla_flags=flag or "")
    if a.dim not in dims:
        return row | dict(note="peer covers " + "/".join(f"{d}D" for d in dims) + " only")
    if importlib.util.find_spec(module) is None:
        return row | dict(note="not installed")
    if not (Path(a.peers) / script).is_file():
        return row | dict(note=f"no {script} in --peers {a.peers}")
    scale = 1.0 if a.match is None else (a.match + 0.5) / peer_particles(a.dim, a.n_grid)  # int() of it: a.match
    cmd = [sys.executable, script, str(a.n_grid), str(a.dim), repr(scale), str(a.steps)] + ([device] if device else [])
    results = [run_child(cmd, child_env(flag), Path(a.peers), a.timeout) for _ in range(a.repeats)]
    ok = [r for r in results if "seconds" in r]
    if not ok:
        return row | dict(note=results[-1].get("note", "failed"))
    sec = statistics.median(r["seconds"] for r in ok)
    n = ok[0]["particles"]
    return row | dict(
        particles=n,
        dt=peer_dt(a.dim, a.n_grid),
        seconds=sec,
        mpart_steps_per_s=n * a.steps / sec / 1e6,
        finite=all(r["finite"] for r in ok),
        device=ok[0].get("device"),
        note=f"peer script, median of {len(ok)} calls: {', '.join('%.3f' % r['seconds'] for r in ok)} s",
    )


def run_jaxmpm_child(name: str, a) -> dict:
    flag = JAXMPM[name][2]
    cmd = [
        sys.executable,
        str(Path(__file__).resolve()),
        "--one",
        name,
        "--dim",
        str(a.dim),
        "--n-grid",
        str(a.n_grid),
        "--steps",
        str(a.steps),
        "--repeats",
        str(a.repeats),
    ]
    cmd += [] if a.ppc is None else ["--ppc", str(a.ppc)]
    r = run_child(cmd, child_env(flag), HERE.parent, a.timeout)
    return dict(config=name, dim=a.dim, n_grid=a.n_grid, steps=a.steps) | r | dict(xla_flags=flag or "")


def complete(rows):
    """Add the ratio to the naive JAX peer, the device and the versions to every row; returns
    (device, the common columns)."""
    naive = next((r.get("mpart_steps_per_s") for r in rows if r["config"] == "jax-naive"), None)
    device = next(
        (r["device"] for r in sorted(rows, key=lambda r: not r["config"].startswith("jaxmpm")) if r.get("device")), ""
    )  # a jaxmpm child's (the device's model included), else a JAX peer's
    common = dict(
        cpu_count=os.cpu_count(),
        jax_version=importlib.metadata.version("jax"),
        date=datetime.datetime.now().isoformat(timespec="seconds"),
    )
    for r in rows:
        rate = r.get("mpart_steps_per_s")
        r["ratio_to_jax_naive"] = rate / naive if rate and naive else None
        r.update(common | dict(device=device))
    return device, common


def write_table(rows, out):
    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)


def fmt(v, spec):
    return "" if v is None or v == "" else format(v, spec)


def plot(rows, path):
    """Horizontal bars of Mpart-steps/s per configuration (peers grey, jaxmpm blue), written to path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r.get("mpart_steps_per_s") not in (None, "")]
    names = [r["config"] for r in rows]
    rates = [float(r["mpart_steps_per_s"]) for r in rows]
    colors = ["C0" if n.startswith("jaxmpm") else "0.6" for n in names]
    fig, ax = plt.subplots(figsize=(7, 0.45 * len(rows) + 1.2))
    y = range(len(rows))[::-1]
    ax.barh(list(y), rates, color=colors)
    for yi, r in zip(y, rates):
        ax.text(r, yi, f" {r:.2f}", va="center", fontsize="small")
    ax.set_yticks(list(y), names)
    ax.set_xlabel("Mpart-steps/s (higher is faster)")
    r0 = rows[0] if rows else {}
    ax.set_title(
        f"mpm88 {r0.get('dim', '')}D, {r0.get('n_grid', '')}^{r0.get('dim', '')} grid, float32; "
        f"{r0.get('device', '')}, {r0.get('cpu_count', '')} CPUs",
        fontsize="medium",
    )
    ax.set_xlim(0, 1.15 * max(rates, default=1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    ap.add_argument("--n-grid", type=int, default=None, help="grid cells per axis (default 128 in 2D, 64 in 3D)")
    ap.add_argument("--steps", type=int, default=None, help="steps per timed run (default 500 in 2D, 100 in 3D)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs; the median is reported")
    ap.add_argument("--only", choices=("jaxmpm", "peers"), default=None)
    ap.add_argument(
        "--configs",
        default=None,
        help="comma-separated configurations to run (default: all; where JAX's "
        "default backend is a GPU, all but the CPU-only " + ", ".join(CPU_ONLY) + ")",
    )
    ap.add_argument(
        "--peers", default=str(PEERS_DIR), help="folder of the peer scripts (default ../shared/bench/peers)"
    )
    ap.add_argument(
        "--ppc",
        type=int,
        default=None,
        help="jaxmpm's particles per cell per axis (1-8), and the peers "
        "run the same number of particles (default: each its own count)",
    )
    ap.add_argument("--timeout", type=float, default=900, help="seconds for each configuration's process (default 900)")
    ap.add_argument(
        "--out",
        default=None,
        help="CSV to write (default results/throughput.csv in 2D, results/throughput_3d.csv in 3D)",
    )
    ap.add_argument("--replot", default=None, metavar="CSV", help="only draw the PNG of a table this script wrote")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # child mode: one jaxmpm config
    ap.add_argument("--one-count", action="store_true", help=argparse.SUPPRESS)  # child mode: jaxmpm's particle count
    add_overwrite(ap)
    a = ap.parse_args(argv)
    if a.replot:
        table = check_table(a.replot)
        png = table.with_suffix(".png")
        check_outputs(png, overwrite=a.overwrite)
        with open(table, newline="") as f:
            rows = list(csv.DictReader(f))
        plot(rows, png)
        print(f"wrote {png}")
        return
    a.n_grid = a.n_grid or (128 if a.dim == 2 else 64)
    a.steps = a.steps or (500 if a.dim == 2 else 100)

    if a.ppc is not None and not 1 <= a.ppc <= 8:
        ap.error(f"--ppc {a.ppc} is invalid: allowed an integer in 1..8")
    if a.one:
        print(json.dumps(run_jaxmpm(a.one, a.dim, a.n_grid, a.steps, a.repeats, a.ppc)))
        return
    if a.one_count:
        print(
            len(
                __import__("jaxmpm.model.sampling", fromlist=["sample_phase"]).sample_phase(
                    *(lambda s: (s.grid, s.phases[0]))(mpm88_scene(a.n_grid, a.dim, a.ppc))
                )
            )
        )
        return
    out = Path(a.out) if a.out else HERE / "results" / ("throughput.csv" if a.dim == 2 else "throughput_3d.csv")
    check_outputs(out, out.with_suffix(".png"), overwrite=a.overwrite)

    rows = []
    names = ([] if a.only == "jaxmpm" else list(PEERS)) + ([] if a.only == "peers" else list(JAXMPM))
    if a.configs:
        wanted = [c.strip() for c in a.configs.split(",") if c.strip()]
        unknown = sorted(set(wanted) - set(PEERS) - set(JAXMPM))
        if unknown:
            ap.error(f"--configs {','.join(unknown)} is invalid: allowed {', '.join(list(PEERS) + list(JAXMPM))}")
        names = list(dict.fromkeys(wanted))  # in the order given
    else:
        left_out = CPU_ONLY if default_backend() != "cpu" else GPU_ONLY
        names = [n for n in names if n not in left_out]
    a.match = None
    if a.ppc is not None:  # jaxmpm's particle count, from a CPU-only child (the parent keeps no device)
        p = subprocess.run(
            [
                sys.executable,
                str(Path(__file__).resolve()),
                "--one-count",
                "--dim",
                str(a.dim),
                "--n-grid",
                str(a.n_grid),
                "--ppc",
                str(a.ppc),
            ],
            capture_output=True,
            text=True,
            env=dict(os.environ, JAX_PLATFORMS="cpu"),
            cwd=HERE.parent,
        )
        if p.returncode != 0:
            sys.exit(f"--ppc {a.ppc}: counting jaxmpm's particles failed: {p.stderr.strip()[-500:]}")
        a.match = int(p.stdout.strip().splitlines()[-1])
        print(f"--ppc {a.ppc}: {a.match} particles in every row", file=sys.stderr, flush=True)
    for name in names:
        t0 = time.perf_counter()
        row = run_peer(name, a) if name in PEERS else run_jaxmpm_child(name, a)
        print(
            f"  {name:20s} {fmt(row.get('mpart_steps_per_s'), '.3f'):>8s} Mpart-steps/s  "
            f"({time.perf_counter() - t0:.0f} s wall)  {row.get('note', '')}",
            file=sys.stderr,
            flush=True,
        )
        rows.append(row)
        device, common = complete(rows)
        write_table(rows, out)  # after every row: a run stopped at a time limit keeps its rows

    # the table
    print(
        f"\nmpm88 {a.dim}D, {a.n_grid}^{a.dim} grid, float32, dt = {peer_dt(a.dim, a.n_grid):.3g} s; "
        f"device {device}, {common['cpu_count']} CPUs, jax {common['jax_version']}"
    )
    head = f"{'config':20s} {'particles':>9s} {'steps':>5s} {'s':>8s} {'Mpart-steps/s':>13s} {'x naive':>7s} {'finite':>6s} {'stable':>6s}  note"
    print(head + "\n" + "-" * len(head))
    for r in rows:
        yn = lambda k: "" if r.get(k) is None else ("yes" if r[k] else "NO")
        print(
            f"{r['config']:20s} {fmt(r.get('particles'), 'd'):>9s} {r['steps']:>5d} {fmt(r.get('seconds'), '.3f'):>8s} "
            f"{fmt(r.get('mpart_steps_per_s'), '.3f'):>13s} {fmt(r.get('ratio_to_jax_naive'), '.2f'):>7s} {yn('finite'):>6s} {yn('stable'):>6s}  "
            f"{'compile %.1f s; ' % r['compile_s'] if r.get('compile_s') else ''}"
            f"{'%s kernels, %s launches/step; ' % (r['kernels'], r['launches_per_step']) if r.get('kernels') else ''}"
            f"{r.get('note', '')}"
        )

    plot(rows, out.with_suffix(".png"))
    print(f"\nwrote {out} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
