"""jaxmpm: differentiable multi-velocity (multiphase) Material Point Method with DDMP, in JAX.

scene  = jaxmpm.load_scene("elastic_impact")
params = jaxmpm.default_params(scene)
state  = jaxmpm.initial_state(scene, params)        # init_state, plus a built-in's own initial fields
step   = jaxmpm.make_step(scene)                   # pure: step(params, state) -> state
fast   = jaxmpm.jit(step)                          # jax.jit with jaxmpm's XLA options (compile.py)
final, history = jaxmpm.simulate(scene, params, state, t_end=..., n_out=10)
final, history = jaxmpm.ensemble(scene, jaxmpm.batch.sweep(params, cfl=[0.2, 0.3]), t_end=...)

Layers, each importing only from those below it (docs/architecture.md):
  materials/  constitutive laws and the material library
  model/      Scene, Params, State, geometry, sampling and its memory checks
  numerics/   shape functions, transfers, DDMP stencils, compiler options
  stages/     the step's stages (Layout, grid stage, constitutive update)
  step.py     make_step: the stages composed
  scenes/     built-in scenes;  io/  output files, plots, scene files
  run/        simulate, planning, restart files, ensembles, devices;  cli.py  the command
"""

from jaxmpm import diagnostics as diagnostics
from jaxmpm import features as features
from jaxmpm import io as io
from jaxmpm import moved
from jaxmpm.io.scenefile import (
    load_scene as load_scene,
    scene_from_dict as scene_from_dict,
    scene_to_toml as scene_to_toml,
)
from jaxmpm.materials import Material as Material
from jaxmpm.model.params import Params as Params, check_params as check_params, default_params as default_params
from jaxmpm.model.scene import (
    Boundary as Boundary,
    Box as Box,
    Difference as Difference,
    Grid as Grid,
    Phase as Phase,
    Scene as Scene,
    Sphere as Sphere,
)
from jaxmpm.model.state import State as State, init_state as init_state
from jaxmpm.numerics import forms as forms
from jaxmpm.numerics.compile import jit as jit
from jaxmpm.run import batch as batch
from jaxmpm.run import compile_cache as compile_cache
from jaxmpm.run import distributed as distributed
from jaxmpm.run import restart as restart
from jaxmpm.run.batch import ensemble as ensemble
from jaxmpm.run.planning import cfl_limit as cfl_limit, plan_steps as plan_steps
from jaxmpm.run.simulate import simulate as simulate
from jaxmpm.scenes import initial_state as initial_state
from jaxmpm.step import make_step as make_step
from jaxmpm.version import __version__ as __version__

moved.register()


def __getattr__(name: str):
    """Old module paths as attributes (`jaxmpm.state` after `import jaxmpm.state`): jaxmpm.moved."""
    return moved.old_module(name)
