"""jaxmpm: differentiable multi-velocity (multiphase) Material Point Method with DDMP, in JAX.

scene  = jaxmpm.load_scene("elastic_impact")
params = jaxmpm.default_params(scene)
state  = jaxmpm.initial_state(scene, params)        # init_state, plus a built-in's own initial fields
step   = jaxmpm.make_step(scene)                   # pure: step(params, state) -> state
fast   = jaxmpm.jit(step)                          # jax.jit with jaxmpm's XLA options (compile.py)
final, history = jaxmpm.simulate(scene, params, state, t_end=..., n_out=10)
final, history = jaxmpm.ensemble(scene, jaxmpm.batch.sweep(params, cfl=[0.2, 0.3]), t_end=...)
"""

from jaxmpm import batch as batch
from jaxmpm import diagnostics as diagnostics
from jaxmpm import distributed as distributed
from jaxmpm import features as features
from jaxmpm.batch import ensemble as ensemble
from jaxmpm.compile import jit as jit
from jaxmpm import compile_cache as compile_cache
from jaxmpm import forms as forms
from jaxmpm import io as io
from jaxmpm.materials import Material as Material
from jaxmpm.params import Params as Params, check_params as check_params, default_params as default_params
from jaxmpm import restart as restart
from jaxmpm.scene import (
    Boundary as Boundary,
    Box as Box,
    Difference as Difference,
    Grid as Grid,
    Phase as Phase,
    Scene as Scene,
    Sphere as Sphere,
)
from jaxmpm.scenefile import (
    load_scene as load_scene,
    scene_from_dict as scene_from_dict,
    scene_to_toml as scene_to_toml,
)
from jaxmpm.simulate import cfl_limit as cfl_limit, plan_steps as plan_steps, simulate as simulate
from jaxmpm.state import State as State, init_state as init_state
from jaxmpm.step import make_step as make_step
from jaxmpm.scenes import initial_state as initial_state


def _version() -> str:
    """The installed distribution's version (pyproject.toml); '0+unknown' when run from a checkout
    that is not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("jaxmpm")
    except PackageNotFoundError:
        return "0+unknown"


__version__ = _version()
