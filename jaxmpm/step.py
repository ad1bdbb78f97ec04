"""make_step(scene): the explicit MPM step composed from the stages the scene calls for.

    step(params, state, t_stop=inf, dt=None) -> state      (pure; jit, vmap and grad compose)

Stages (PHYSICS 2.1, ARCHITECTURE), each in its module of jaxmpm.stages: 1 shape functions
(jaxmpm.numerics.shapes), 2 particle to grid (`particle_to_grid`: a `NodalSums`), 3 grid update
(`grid_update`: a `GridUpdate`), 4 grid to particle with the seed's update and remap
(`grid_to_particle`), 5 constitutive update per phase (`constitutive`: a `ConstitutiveUpdate`);
the APIC step in `apic`. Everything an effect needs is chosen in Python, before tracing: an effect
the scene does not name (gravity, damping, body force, DDMP, a wall) is not in the traced program
at all.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from jaxmpm.model.params import Params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State

from dataclasses import replace

import jax
import jax.numpy as jnp

from jaxmpm.numerics.shapes import ddmp_beta, stencil
from jaxmpm.stages.apic import apic_update
from jaxmpm.stages.constitutive import constitutive
from jaxmpm.stages.grid_to_particle import grid_to_particle
from jaxmpm.stages.grid_update import grid_acceleration
from jaxmpm.stages.layout import STAGE_PARTS, STAGES, Layout, mass_floor
from jaxmpm.stages.particle_to_grid import body_acceleration, gravity_now, particle_to_grid
from jaxmpm.stages.phase_models import bulk_modulus_and_wave_speed

# kept importable from here, where they were before they moved into the stages' modules
__all__ = [
    "STAGES",
    "STAGE_PARTS",
    "apic_update",
    "body_acceleration",
    "cfl_time_step",
    "gravity_now",
    "grid_acceleration",
    "make_step",
    "particle_to_grid",
    "seed_update",
    "tangent_fenced",
    "wave_speed",
]


@jax.custom_jvp
def tangent_fenced(x: Any, on: jax.Array) -> Any:
    """x (any array); its tangent taken under lax.cond(on), zero where on is false. Reverse mode
    transposes the conditional, so x's cotangent enters it as one array: XLA cannot fuse the
    cotangent's computation into each of its consumers (where, in the velocity gradient's
    transpose, it was repeated for each stencil node and each consumer). Exact where x's tangent
    does not matter when on is false (the step's dt = 0, whose update the step discards)."""
    return x


@tangent_fenced.defjvp
def _tangent_fenced_jvp(primals, tangents):
    x, on = primals
    dx, _ = tangents
    return x, jax.lax.cond(on, lambda t: t, lambda t: jax.tree.map(jnp.zeros_like, t), dx)


_mass_floor = mass_floor  # its name before it moved into jaxmpm.stages.layout


def wave_speed(scene: Scene, params: Params, state: State) -> jax.Array:
    """(N,) longitudinal wave speed of every particle (m/s) at its current density."""
    return bulk_modulus_and_wave_speed(Layout.of(scene), params, state)[1]


def cfl_time_step(scene: Scene, params: Params, state: State, cfl: jax.Array | None = None) -> jax.Array:
    """dt = CFL h / max_p (c_p + |v_p|) (PHYSICS 2.1), s."""
    return _cfl_time_step(Layout.of(scene), params, state, cfl)


def _cfl_time_step(layout: Layout, params: Params, state: State, cfl: jax.Array | None = None) -> jax.Array:
    cfl = params.cfl if cfl is None else cfl
    v2 = jnp.sum(state.v * state.v, axis=-1)
    moving = v2 > 0
    speed = bulk_modulus_and_wave_speed(layout, params, state)[1] + jnp.where(
        moving, jnp.sqrt(jnp.where(moving, v2, 1.0)), 0.0
    )  # finite grad at rest
    return cfl * layout.scene.grid.h / layout.particle_max(speed)


def seed_update(layout: Layout, params: Params, state: State, dt: jax.Array) -> State:
    """One explicit step with the seed's update (PHYSICS 2.1 step 4) and linear, DDMP or B-spline
    gradients: v_p += dt sum_n a_n S_np, a remap of the particle momentum to the grid, and the
    stress driven by the gradient of the remapped velocity. Three variants (scene.transfer):

      'musl' (default): remap at the positions of this step, v_n = sum m_p v_p^new S_np / m_n;
        particles move with it, x_p += dt sum_n v_n S_np, and L_p is its gradient at the same
        positions with the same operators as the force (E11/E12 adjoint). Positions, F and stress
        follow one velocity field; a contact dissipates (inelastic merge of nodal momenta).
      'seed': remap at the new positions (the seed's m_i u_i = sum m_p u_p S_i(x_p^new)),
        x_p += dt sum_n (v_n + a_n dt) S_np. A 200 m/s single-field impact GAINS 11% energy at
        CFL 0.3 with it (1.5% at CFL 0.05), 'musl' loses 6%: tests/test_update_schemes.py.
      'seed_halfstep': as 'seed' with the seed's literal x_p += dt sum (v_n + a_n dt / 2) S_np,
        which moves particles with a velocity other than the one driving the stress: first order
        in dt (vibrating bar at CFL 0.02, 50 cells: 3.6e-7 m against 1.6e-8 m).
    """
    scene = layout.scene
    m_min = mass_floor(layout, state)
    with jax.named_scope(STAGES[0]):  # 1
        stencils = stencil(scene, state.x)
        beta = ddmp_beta(stencils.xi) if scene.shape == "ddmp" else None
    with jax.named_scope(STAGES[1]):  # 2
        sums = particle_to_grid(layout, params, stencils, state, beta)
        if layout.n_fields == 1:
            # the nodal parts' cotangent as one array: XLA had fused its computation (about 130
            # operations per node) into the transposed scatter's gather, repeated per particle and
            # stencil node. One field: gradients 0.86-1.00 of the time before (elastic impact,
            # Taylor bars, 1D bars, interleaved); two fields 1.01-1.07, where the cotangent's computation
            # moved into the DDMP operators' transposes (benchmarks/NOTES.md, Gradients)
            sums = tangent_fenced(sums, dt > 0)
        acc_p = body_acceleration(layout, params, state)
    with jax.named_scope(STAGES[2]):  # 3
        grid = grid_acceleration(layout, params, state, stencils, beta, sums, acc_p, dt, m_min)
    with jax.named_scope(STAGES[3]):  # 4
        moved, L, p_amb, L_work = grid_to_particle(layout, params, state, stencils, beta, sums, grid, dt, m_min)
    with jax.named_scope(STAGES[4]):  # 5
        # L's cotangent as one array: XLA had fused its computation from the constitutive
        # update's transpose into each consumer in the velocity gradient's transpose, repeated per
        # stencil node (that stage's transpose: 8.8 -> 2.0-2.6 forward runs of it, benchmarks/NOTES.md)
        L_work = None if L_work is None else tangent_fenced(L_work, dt > 0)
        new = constitutive(layout, params, moved, tangent_fenced(L, dt > 0), dt, p_amb, L_work)
    return replace(moved, t=state.t + dt, **new._asdict())


def make_step(scene: Scene, shards: int = 1, axis_name: str | None = None) -> Callable[..., State]:
    """Compose the pure step of `scene`: step(params, state, t_stop=inf, dt=None) -> state.

    t_stop and dt in s. dt defaults to the CFL step (PHYSICS 2.1); it is clipped so that t never passes t_stop, and a
    step with dt = 0 returns the state unchanged (so a fixed-length scan stays differentiable).
    shards, axis_name: the step of one device's block of particles when every phase's particles
    are split in `shards` equal parts along the mesh axis `axis_name` (run it under shard_map:
    `jaxmpm.distributed.make_sharded_step`); scatters are summed and particle maxima taken
    across that axis, the grid update is repeated on every device.
    """
    layout = Layout.of(scene, shards, axis_name)
    update = apic_update if scene.transfer == "apic" else seed_update

    def step(params: Params, state: State, t_stop: float | jax.Array = jnp.inf, dt: jax.Array | None = None) -> State:
        dt = _cfl_time_step(layout, params, state) if dt is None else jnp.asarray(dt, state.t.dtype)
        dt = jnp.clip(jnp.minimum(dt, t_stop - state.t), 0.0, None)
        active = dt > 0
        new = update(layout, params, state, dt)
        return jax.tree.map(lambda a, b: jnp.where(active, a, b), new, state)

    return step
