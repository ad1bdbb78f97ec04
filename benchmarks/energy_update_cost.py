"""What `energy_update = "compatible"` costs per step against the default "midpoint": one more
velocity gradient (of `jaxmpm.stages.grid_to_particle.force_work_velocity`) where a phase is a
hydrocode model.

Scenes (float64, one velocity field): the debris cloud (built-in `debris_cloud`, resolution 1,
`tensile`, C_h = 0.02) and the 1 mm al2024 fragment flying into a slip wall of tests/test_boundary.py
(3 km/s). Each configuration is compiled as a `jaxmpm.jit` loop of --steps steps, run once from the
initial state, then --repeats times from that state, the configurations of a scene interleaved; the
median and the fastest time per step are printed and written to a CSV (--out, default
benchmarks/results/energy_update_cost.csv). On a loaded machine the fastest run is the better
measure of the cost (other processes only add time).

Run:  python benchmarks/energy_update_cost.py
      python benchmarks/energy_update_cost.py --steps 100 --repeats 5
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import jax

import jaxmpm

jax.config.update("jax_enable_x64", True)

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from outputs import add_overwrite, check_outputs  # noqa: E402  benchmarks/outputs.py
from timing import cost_rows, interleaved_ms_per_step, step_loop, write_csv  # noqa: E402  benchmarks/timing.py
from test_boundary import _fragment_scene  # noqa: E402

SCENES = {
    "debris_cloud_res1": lambda: jaxmpm.load_scene(
        "debris_cloud", resolution=1.0, fields=1, c_h=0.02, fragmentation="tensile"
    ),
    "fragment_3km_s": lambda: _fragment_scene(3000.0, False, 3e-6),
}
UPDATES = ("midpoint", "compatible")


def per_step_ms(make_scene, steps, repeats):
    """{energy update: [ms per step of each timed run]}, the two interleaved."""

    def build(update):
        scene = dataclasses.replace(make_scene(), energy_update=update)
        return step_loop(scene, jaxmpm.default_params(scene), steps)

    return interleaved_ms_per_step({u: lambda u=u: build(u) for u in UPDATES}, steps, repeats)


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", default=str(HERE / "results" / "energy_update_cost.csv"))
    add_overwrite(ap)
    args = ap.parse_args(argv)
    out = Path(args.out)
    check_outputs(out, overwrite=args.overwrite)
    rows = []
    for scene_name, make_scene in SCENES.items():
        times = per_step_ms(make_scene, args.steps, args.repeats)
        rows += cost_rows(times, "midpoint", {"scene": scene_name}, "ratio_to_midpoint")
    write_csv(out, "energy_update_cost", rows, "float64")


if __name__ == "__main__":
    main()
