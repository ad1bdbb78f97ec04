"""Run time of the debris cloud in a gas-filled chamber, and its cost per step against the vacuum scene.

Scenes: the built-in `debris_cloud` with `fields = 2` (projectile | plate) in vacuum, and with
`chamber_pressure` (default 10.5 bar: projectile | plate | air, three velocity fields) at each
resolution given (default 0.75 and 1), float64. For each: the whole run to t_end (default the
scene's 6 us, `jaxmpm.simulate` with the CFL step: its number of steps depends on the speeds the
run reaches; the table estimates them from the time per step), timed after a short run that
compiles the same program; and a fixed number of steps (`--steps`, at the initial
CFL step) timed in interleaved rounds, the fastest counting, so that the cost per step of the
chamber against vacuum comes from one stretch of the machine's load. Prints and writes
benchmarks/results/debris_chamber.csv.

    python benchmarks/debris_chamber.py [--resolutions 0.75 1] [--pressure 1.05e6] [--steps 40] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import jax

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs, print_and_write_table  # benchmarks/outputs.py


def build(resolution, pressure, t_end):
    import jaxmpm

    kw = {} if pressure is None else {"chamber_pressure": pressure}
    scene = jaxmpm.load_scene("debris_cloud", resolution=resolution, fields=2, **kw)
    if t_end is not None:
        scene = scene.replace(t_end=t_end)
    params = jaxmpm.default_params(scene)
    return scene, params, jaxmpm.init_state(scene, params)


def whole_run(scene, params, state):
    """(seconds of the run to t_end after a short compiling run, seconds of that compiling run)."""
    import jaxmpm

    t0 = time.perf_counter()
    jax.block_until_ready(jaxmpm.simulate(scene, params, state, t_end=0.01 * scene.t_end, n_out=1, progress=False))
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    final, _ = jaxmpm.simulate(scene, params, state, n_out=1, progress=False)
    jax.block_until_ready(final)
    return time.perf_counter() - t0, first


def fixed_steps(scene, params, state, steps):
    """The compiled run of `steps` steps at a fixed dt (the initial CFL step)."""
    import jaxmpm
    from jaxmpm.step import cfl_time_step

    step = jaxmpm.make_step(scene)
    dt = float(cfl_time_step(scene, params, state))
    run = jaxmpm.jit(
        lambda p, s: jax.lax.scan(lambda c, _: (step(p, c, jax.numpy.inf, dt), None), s, None, length=steps)[0]
    )
    jax.block_until_ready(run(params, state))
    return lambda: jax.block_until_ready(run(params, state))


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--resolutions", type=float, nargs="+", default=[0.75, 1.0])
    ap.add_argument("--pressure", type=float, default=1.05e6, help="the chamber's pressure (Pa)")
    ap.add_argument("--t-end", type=float, default=None, help="s (default: the scene's 6 us)")
    ap.add_argument("--steps", type=int, default=40, help="steps of the per-step timing")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved rounds; the fastest counts")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "debris_chamber.csv"))
    add_overwrite(ap)
    a = ap.parse_args()
    check_outputs(a.out, overwrite=a.overwrite)
    jax.config.update("jax_enable_x64", True)
    rows = []
    for res in a.resolutions:
        cases = {}
        for label, p in (("vacuum", None), ("chamber", a.pressure)):
            scene, params, state = build(res, p, a.t_end)
            seconds, first = whole_run(scene, params, state)
            cases[label] = dict(
                run=fixed_steps(scene, params, state, a.steps),
                row=dict(
                    resolution=res,
                    scene=label,
                    pressure_Pa=0.0 if p is None else p,
                    fields=scene.n_fields,
                    particles=int(state.x.shape[0]),
                    t_end_us=scene.t_end * 1e6,
                    run_s=seconds,
                    compile_s=first,
                ),
            )
        best = {k: float("inf") for k in cases}
        for _ in range(a.repeats):
            for k, c in cases.items():
                t0 = time.perf_counter()
                c["run"]()
                best[k] = min(best[k], time.perf_counter() - t0)
        for k, c in cases.items():
            r = c["row"]
            r["ms_per_step"] = 1e3 * best[k] / a.steps
            r["step_cost_vs_vacuum"] = best[k] / best["vacuum"]
            r["run_steps_estimate"] = round(r["run_s"] / (best[k] / a.steps))
            rows.append(r)
    print(
        f"debris cloud in a {a.pressure:g} Pa chamber against vacuum, float64, {describe()}, "
        f"{os.cpu_count()} CPUs, jax {jax.__version__}, {platform.machine()}"
    )
    print_and_write_table(rows, a.out)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
