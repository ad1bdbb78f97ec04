"""What the fluids' stabilisation costs per step, and what the step cost before it:
  - the density diffusion of fluid phases (`jaxmpm.stages.density_diffusion.density_diffusion_rate`: one scatter of
    two channels and one gather a step), on and off;
  - linear_fluid's pressure from the particle's volume ratio (now) or from det F of the forward
    update F = (I + dt L) F (before).
Scenes: the dam break of tests/test_fluids.py (20 cells per a, Tait water) and the peers' mpm88
(128^2, linear_fluid) with DDMP and 'musl', float32.

"off" replaces `jaxmpm.stages.grid_to_particle.diffused_particles` with one that marks no particle, "det F" the
linear_fluid model with the one of before: both only for this measurement. Each configuration is
compiled as a `jaxmpm.jit` loop of --steps steps, run once from the initial state, then --repeats
times from that state, the configurations of a scene interleaved; the median and the fastest time
per step are printed and written to a CSV (--out, default
benchmarks/results/fluid_stabilisation_cost.csv). On a loaded machine the fastest run is the
better measure of the cost (other processes only add time).

Run:  python benchmarks/fluid_stabilisation_cost.py
      python benchmarks/fluid_stabilisation_cost.py --steps 500 --repeats 7
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
from pathlib import Path

import jax.numpy as jnp

import jaxmpm
from jaxmpm.stages import grid_to_particle as step_module
from jaxmpm.materials import elastic, models

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
from outputs import add_overwrite, check_outputs  # noqa: E402  benchmarks/outputs.py
from timing import cost_rows, interleaved_ms_per_step, step_loop, write_csv  # noqa: E402  benchmarks/timing.py
from test_fluids import dam_break  # noqa: E402


@contextlib.contextmanager
def diffusion_off():
    keep = step_module.diffused_particles
    step_module.diffused_particles = lambda lay: None
    try:
        yield
    finally:
        step_module.diffused_particles = keep


@contextlib.contextmanager
def pressure_from_det_F():
    keep = models.MODELS["linear_fluid"]
    models.MODELS["linear_fluid"] = dataclasses.replace(keep, update=models._total_stress(elastic.linear_fluid_update))
    try:
        yield
    finally:
        models.MODELS["linear_fluid"] = keep


SCENES = {
    "dam_break_20": (lambda: dam_break(20, 8.0), {"default": (), "diffusion off": (diffusion_off,)}),
    "mpm88_ddmp": (
        lambda: dataclasses.replace(jaxmpm.load_scene("mpm88"), shape="ddmp", transfer="musl"),
        {
            "default": (),
            "diffusion off": (diffusion_off,),
            "diffusion off, det F pressure (before)": (diffusion_off, pressure_from_det_F),
        },
    ),
}


def per_step_ms(make_scene, configs, steps, repeats):
    """{config: [ms per step of each timed run]} with the configurations interleaved."""

    def build(patches):
        with contextlib.ExitStack() as stack:
            for patch in patches:
                stack.enter_context(patch())
            scene = make_scene()
            return step_loop(scene, jaxmpm.default_params(scene, dtype=jnp.float32), steps)  # traced here

    return interleaved_ms_per_step({name: lambda p=p: build(p) for name, p in configs.items()}, steps, repeats)


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", default=str(HERE / "results" / "fluid_stabilisation_cost.csv"))
    add_overwrite(ap)
    args = ap.parse_args(argv)
    out = Path(args.out)
    check_outputs(out, overwrite=args.overwrite)
    rows = []
    for scene_name, (make_scene, configs) in SCENES.items():
        times = per_step_ms(make_scene, configs, args.steps, args.repeats)
        rows += cost_rows(times, "default", {"scene": scene_name}, "ratio_to_default")
    write_csv(out, "fluid_stabilisation_cost", rows, "float32")


if __name__ == "__main__":
    main()
