"""What the fluids' default artificial viscosity costs per step: the dam break of
tests/test_fluids.py (DDMP, 'musl') with it (the default) and without (artificial_viscosity (0, 0)).

Each configuration is compiled as a `jaxmpm.jit` loop of --steps steps, run once from the initial
state, then --repeats times from that state, the two configurations interleaved; the median time
per step is printed and written to a CSV (--out, default benchmarks/results/fluid_viscosity_cost.csv).

Run:  python benchmarks/fluid_viscosity_cost.py                 # 20 cells per a, float32 and float64
      python benchmarks/fluid_viscosity_cost.py --cells 40 --repeats 7
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

import jaxmpm  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from outputs import add_overwrite, check_outputs  # noqa: E402  benchmarks/outputs.py
from timing import interleaved_ms_per_step, step_loop, write_csv  # noqa: E402  benchmarks/timing.py
from test_fluids import dam_break  # noqa: E402

CONFIGS = {"default (viscosity on fluids)": None, "artificial_viscosity (0, 0)": (0.0, 0.0)}


def per_step_ms(cells, dtype, steps, repeats):
    """{config: [ms per step of each timed run]} with the configurations interleaved."""

    def build(av):
        scene = dam_break(cells, 8.0, artificial_viscosity=av)
        return step_loop(scene, jaxmpm.default_params(scene, dtype=dtype), steps)

    return interleaved_ms_per_step({name: lambda av=av: build(av) for name, av in CONFIGS.items()}, steps, repeats)


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--cells", type=int, default=20, help="cells per column width a")
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=str(HERE / "results" / "fluid_viscosity_cost.csv"))
    add_overwrite(ap)
    args = ap.parse_args(argv)
    out = Path(args.out)
    check_outputs(out, overwrite=args.overwrite)
    rows = []
    for dtype in (jnp.float32, jnp.float64):
        times = per_step_ms(args.cells, dtype, args.steps, args.repeats)
        base = statistics.median(times["artificial_viscosity (0, 0)"])
        for name, t in times.items():
            rows.append(
                {
                    "cells_per_a": args.cells,
                    "dtype": jnp.dtype(dtype).name,
                    "config": name,
                    "ms_per_step": statistics.median(t),
                    "ratio_to_off": statistics.median(t) / base,
                    "runs_ms": " ".join(f"{x:.3f}" for x in t),
                }
            )
            print(
                f"{rows[-1]['dtype']:8s} {name:30s} {rows[-1]['ms_per_step']:.3f} ms/step, x{rows[-1]['ratio_to_off']:.3f} "
                f"(runs {rows[-1]['runs_ms']})",
                flush=True,
            )
    write_csv(out, "fluid_viscosity_cost", rows)


if __name__ == "__main__":
    main()
