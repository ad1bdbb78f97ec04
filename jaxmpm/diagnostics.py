"""Diagnostics of a State: mass, momentum and energy per phase and in total (SI units).

All functions are pure and jit/vmap/grad-compatible; `summary` returns host floats.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxmpm.materials.models import model_of
from jaxmpm.model.params import Params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State, particle_fields, phase_slices
from jaxmpm.numerics.ddmp import node_support
from jaxmpm.numerics.shapes import linear_stencil
from jaxmpm.numerics.transfer import scatter_weighted


def total_mass(state: State) -> jax.Array:
    """kg (per unit depth in 2D, kg/m; per unit area in 1D; per radian in axisymmetric scenes)."""
    return jnp.sum(state.mass)


def momentum(state: State) -> jax.Array:
    """(d,) total linear momentum, kg m/s (per unit depth in 2D, kg/s; per unit area in 1D; per
    radian in axisymmetric scenes, where only its axial component z is conserved)."""
    return jnp.sum(state.mass[:, None] * state.v, axis=0)


def kinetic_energy(state: State) -> jax.Array:
    """J (per unit depth in 2D, J/m; per unit area in 1D; per radian in axisymmetric scenes)."""
    return 0.5 * jnp.sum(state.mass * jnp.sum(state.v**2, axis=-1))


def internal_energy(state: State) -> jax.Array:
    """sum_p m_p e_p, J (per unit depth, area or radian as `kinetic_energy`): the work done on the
    particles by their stress (strain energy, heat)."""
    return jnp.sum(state.mass * state.energy)


def gravitational_energy(state: State, gravity: ArrayLike) -> jax.Array:
    """- sum_p m_p g . x_p, J (per unit depth, area or radian as `kinetic_energy`; zero at the
    origin). gravity: (d,) m/s^2."""
    return -jnp.sum(state.mass * (state.x @ gravity))


def strain_energy(scene: Scene, params: Params, state: State) -> jax.Array | float:
    """Elastic energy from F for phases whose model defines it (else from the energy integral), J."""
    total = 0.0
    for p, sl in zip(scene.phases, phase_slices(scene)):
        model = model_of(scene.material(p).model)
        if model.strain_energy is not None:
            V0 = state.mass[sl] / params.phases[p.name]["rho0"]
            total = total + jnp.sum(V0 * model.strain_energy(params.phases[p.name], state.F[sl]))
        else:
            total = total + jnp.sum(state.mass[sl] * state.energy[sl])
    return total


def surroundings_energy(state: State, ambient_pressure: ArrayLike) -> jax.Array:
    """p_a sum_p V_p, J (per unit depth, area or radian as `kinetic_energy`): the work the material
    would do against surroundings at the pressure p_a (Pa) to take its volume (Scene.ambient_pressure:
    they do -p_a dV/dt on it)."""
    return ambient_pressure * jnp.sum(state.volume)


def total_energy(scene: Scene, params: Params, state: State) -> jax.Array:
    """Kinetic + internal (+ gravitational where the scene has gravity, + p_a V where it has an
    ambient pressure p_a: `surroundings_energy`), J."""
    e = kinetic_energy(state) + internal_energy(state)
    if scene.gravity is not None:
        e = e + gravitational_energy(state, params.gravity)
    if scene.ambient_pressure is not None:
        e = e + surroundings_energy(state, params.ambient_pressure)
    return e


def per_phase(scene: Scene, state: State) -> dict[str, dict[str, jax.Array]]:
    """{phase: {mass, momentum, kinetic, internal}} as arrays."""
    out = {}
    for p, sl in zip(scene.phases, phase_slices(scene)):
        m, v = state.mass[sl], state.v[sl]
        out[p.name] = {
            "mass": jnp.sum(m),
            "momentum": jnp.sum(m[:, None] * v, 0),
            "kinetic": 0.5 * jnp.sum(m * jnp.sum(v**2, -1)),
            "internal": jnp.sum(m * state.energy[sl]),
        }
    return out


def summary(scene: Scene, params: Params, state: State) -> dict:
    """Host-side floats: time, mass, momentum, kinetic, internal and total energy."""
    return {
        "t": float(state.t),
        "mass": float(total_mass(state)),
        "momentum": [float(a) for a in momentum(state)],
        "kinetic": float(kinetic_energy(state)),
        "internal": float(internal_energy(state)),
        "total_energy": float(total_energy(scene, params, state)),
    }


def volume_fractions(scene: Scene, state: State) -> tuple[jax.Array, jax.Array]:
    """Nodal volume fractions theta_nk = sum_{p in k} V_p S_np / V_n of every velocity field,
    (K, *nodes), and their sum Theta = sum_k theta_k, (*nodes,) (E7 asks Theta = 1 in a mixture)."""
    grid = scene.grid
    K = scene.n_fields
    field = jnp.asarray(particle_fields(scene)) if K > 1 else None
    vol = scatter_weighted(linear_stencil(grid, state.x), field, state.volume[:, None], K, grid.n_nodes)[..., 0]
    theta = (vol / jnp.asarray(node_support(grid, scene.axisymmetric).reshape(-1), vol.dtype)).reshape(
        (K,) + grid.nodes
    )
    return theta, jnp.sum(theta, 0)
