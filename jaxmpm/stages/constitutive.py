"""Stage 5 of the step: the constitutive update of every phase by its model kind, the material
volume rate with the continuous-to-disperse closure (E4, E5, E8: `jaxmpm.stages.closure`),
artificial viscosity and the internal energy.

Shapes: N particles, d dimensions; SI units.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from jaxmpm.materials.models import MatPoint
from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.stages.closure import (
    alpha_of_strain,
    fragmentation_gate,
    material_volume_rate,
    pressure_factor,
    tensile_fragment_fraction,
    tension_mask,
)
from jaxmpm.stages.layout import Layout
from jaxmpm.stages.phase_models import bulk_modulus_and_wave_speed, per_model, pressure


def artificial_viscosity(layout: Layout, params: Params, state: State, rho_new: jax.Array, trD: jax.Array) -> jax.Array:
    """von Neumann-Richtmyer pressure q = rho l (c_q l (tr D)^2 - c_l c tr D) in compression
    (tr D < 0), 0 in expansion; l the cell size h, c the bulk sound speed. (N,) Pa"""
    K, _ = bulk_modulus_and_wave_speed(layout, params, state)
    c = jnp.sqrt(K / (state.mass / state.volume))
    l = layout.scene.grid.h
    comp = jnp.minimum(trD, 0.0)
    c_linear, c_quadratic = params.artificial_viscosity[0], params.artificial_viscosity[1]
    return rho_new * l * (c_quadratic * l * comp**2 - c_linear * c * comp)


def viscous_particles(layout: Layout) -> np.ndarray:
    """(N,) static bool: whether each particle's phase takes the artificial viscosity
    (scene.viscous_phases)."""
    return np.concatenate(
        [np.full(sl.stop - sl.start, on, bool) for on, sl in zip(layout.scene.viscous_phases, layout.slices)]
    )


class ConstitutiveUpdate(NamedTuple):
    """What the constitutive stage (5) gives the step: the new values of these State fields (N
    particles, m the material dimension: 3 axisymmetric, else d)."""

    F: jax.Array  # (N, m, m) deformation gradient
    stress: jax.Array  # (N, m, m) Cauchy stress, Pa
    volume: jax.Array  # (N,) m^3 (per radian axisymmetric)
    energy: jax.Array  # (N,) J/kg specific internal energy
    eps_ps: jax.Array  # (N,) equivalent plastic strain
    pressure: jax.Array  # (N,) Pa
    damage: jax.Array  # (N,) in [0, 1]

    def __getitem__(self, key):
        """A field by name (new["F"], as the dict of the versions before), or by position."""
        return getattr(self, key) if isinstance(key, str) else tuple.__getitem__(self, key)


def constitutive(
    layout: Layout,
    params: Params,
    state: State,
    L: jax.Array,
    dt: ArrayLike,
    p_amb: jax.Array | None = None,
    L_work: jax.Array | None = None,
) -> ConstitutiveUpdate:
    """Stage 5: volume V *= exp(dt tr L) (or the material rate of the closure, E4); per phase, its
    model's update of F, stress, pressure, internal energy, plastic strain and damage. Returns a
    `ConstitutiveUpdate` (the new values of those State fields).
    Internal energy: with L_work (N, d, d) 1/s, the velocity gradient the grid's forces did work
    with over the step (`grid_to_particle`, energy_update 'compatible'), the hydrocode models take
    the work of the start stress sigma_f^n on it, de = dt V^n sigma_f^n : sym(L_work) / m (with an
    ambient pressure p_a, the grid's gauge stress and p_a on the volume change: the total energy
    exact); else, and for the total-stress kinds, de = dt V_mid sigma_f:D / m with midpoint values
    (sigma_f the stress the grid sees)."""
    # longer than 60 lines on purpose: stage 5 in its order (the closure's volume rate, E4; the artificial
    # viscosity; each phase's model; the tensile fragments), each step reading the arrays of the ones before
    scene = layout.scene
    d = L.shape[-1]
    L_mat, rate = L, jnp.trace(L, axis1=1, axis2=2)
    carried = rate  # the volume rate the velocity field imposes on the material (E4's a div<v>)
    gate = None
    D = 0.5 * (L + jnp.swapaxes(L, 1, 2))
    tensile = scene.has_closure and scene.fragmentation == "tensile"
    if scene.has_closure:
        p_amb = jnp.zeros_like(state.mass) if p_amb is None else p_amb
        rate = material_volume_rate(layout, params, state, L, dt, p_amb)
        carried = pressure_factor(layout, params, state) * jnp.trace(L, axis1=1, axis2=2)
        L_mat = L + ((rate - jnp.trace(L, axis1=1, axis2=2)) / d)[:, None, None] * jnp.eye(d, dtype=L.dtype)
        gate = tension_mask(layout, state) if tensile else fragmentation_gate(layout, state)
    vol = state.volume * jnp.exp(dt * rate)
    rho_new = state.mass / vol
    q = None
    if scene.viscosity is not None:
        # q damps the velocity field's compression (a tr D, E4), not the closure's relaxation B (E8):
        # a fragment contracting to relieve its own tension is no shock. Driven by B, q turned
        # tensile fragments' pressure positive, the pressure's factor a to 1, and the fragments
        # pushed their neighbours with a pressure no velocity field compressed (docs/closure.md)
        q = artificial_viscosity(layout, params, state, rho_new, carried)
        if not all(scene.viscous_phases):
            q = jnp.where(jnp.asarray(viscous_particles(layout)), q, 0.0)
    work = dt * 0.5 * (vol + state.volume) / state.mass
    mp = MatPoint(
        state.F,
        state.stress,
        pressure(layout, state),
        state.energy,
        state.eps_ps,
        state.damage,
        state.mass / state.volume,
        rho_new,
    )

    D_f = None if L_work is None else 0.5 * (L_work + jnp.swapaxes(L_work, 1, 2))
    work_start = None if L_work is None else dt * state.volume / state.mass
    ambient_work = None
    if L_work is not None and scene.ambient_pressure is not None:
        # the grid saw the gauge stress sigma + p_a I, and the surroundings' energy p_a V follows the
        # volume itself: de += p_a (dt V^n tr D_f - (V^{n+1} - V^n)) / m keeps the total exact
        p_a = params.ambient_pressure
        ambient_work = p_a * (work_start * jnp.trace(D_f, axis1=1, axis2=2) - (vol - state.volume) / state.mass)

    def update(model, c, L_mat, D, work, q, gate, D_f, work_start, ambient_work, *mp):
        m0 = MatPoint(*mp)
        alpha_of = alpha_of_strain(tensile, params.c_h, gate, m0.eps_ps, m0.damage, m0.pressure)
        force_work = None if D_f is None else (D_f, work_start, ambient_work)
        return tuple(model.update(c, m0, L_mat, D, dt, work, q, alpha_of, force_work))

    new = MatPoint(*per_model(layout, params, update, L_mat, D, work, q, gate, D_f, work_start, ambient_work, *mp))
    damage = new.damage
    if tensile:
        damage = tensile_fragment_fraction(params.c_h, damage, gate * jnp.maximum(new.eps_ps - state.eps_ps, 0.0))
    return ConstitutiveUpdate(
        F=new.F,
        stress=new.stress,
        volume=vol,
        energy=new.energy,
        eps_ps=new.eps_ps,
        pressure=new.pressure,
        damage=damage,
    )
