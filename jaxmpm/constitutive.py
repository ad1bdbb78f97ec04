"""Stage 5 of the step: the constitutive update of every phase by its model kind, the material
volume rate with the continuous-to-disperse closure (E4, E5, E8) and the internal energy.

Shapes: N particles, d dimensions; SI units.
"""
from __future__ import annotations

from dataclasses import replace

import jax.numpy as jnp

from jaxmpm.materials.models import MODELS


def closure_alpha(params, state):
    """(E5) alpha = 1 - tanh(eps_ps / C_h): 1 for intact material, -> 0 when fragmented. (N,)"""
    return 1.0 - jnp.tanh(state.eps_ps / params.c_h)


def force_stress(lay, params, state):
    """Stress whose divergence the grid sees (N, d, d): with the closure (E8) the isotropic part
    scaled by alpha, sigma + (1 - alpha) p I, so a fragmented material does no work through a
    volume change it does not have."""
    if lay.scene.c_h is None:
        return state.stress
    d = lay.dim
    p = -jnp.trace(state.stress, axis1=1, axis2=2) / d
    return state.stress + ((1 - closure_alpha(params, state)) * p)[:, None, None] * jnp.eye(d, dtype=p.dtype)


def material_volume_rate(lay, params, state, L, dt, p_amb):
    """(E4) <div v_i> = alpha_i div<v_i> + B_i with (E5) alpha and the closure (E8)
    B_i = (1 - alpha_i)(p_i - p_amb) / (K_i tau_i), tau_i = h / c_i, taken as the exact exponential
    relaxation over the step, (1 - exp(-dt / tau)) / dt. p_amb: (N,) ambient pressure (Pa). (N,) 1/s."""
    scene = lay.scene
    alpha = closure_alpha(params, state)
    rho = state.mass / state.volume
    K, c = [], []
    for p, sl in zip(scene.phases, lay.slices):
        model = MODELS[scene.material(p).model]
        K.append(model.bulk_modulus(params.phases[p.name], rho[sl], lay.dim))
        c.append(model.wave_speed(params.phases[p.name], rho[sl], lay.dim) * jnp.ones_like(rho[sl]))
    K, c = jnp.concatenate(K), jnp.concatenate(c)
    tau = scene.grid.h / c
    p = -jnp.trace(state.stress, axis1=1, axis2=2) / lay.dim
    x = dt / tau
    relax = jnp.where(x > 1e-8, -jnp.expm1(-x) / jnp.where(x > 1e-8, x, 1.0), 1.0) / tau
    B = (1 - alpha) * (p - p_amb) / K * relax
    return alpha * jnp.trace(L, axis1=1, axis2=2) + B


def constitutive(lay, params, state, L, dt, p_amb=None):
    """Stage 5: per phase, its model's stress update; volume V *= exp(dt tr L) (or the material
    rate of the closure, E4); internal energy de = dt V sigma_f:D / m with midpoint values, sigma_f
    the stress the grid sees (with the closure the energy its relaxation releases stays as heat)."""
    scene = lay.scene
    d = lay.dim
    L_mat, rate = L, jnp.trace(L, axis1=1, axis2=2)
    if scene.c_h is not None:
        p_amb = jnp.zeros_like(state.mass) if p_amb is None else p_amb
        rate = material_volume_rate(lay, params, state, L, dt, p_amb)
        L_mat = L + ((rate - jnp.trace(L, axis1=1, axis2=2)) / d)[:, None, None] * jnp.eye(d, dtype=L.dtype)
    Fs, sigs = [], []
    for p, sl in zip(scene.phases, lay.slices):
        model = MODELS[scene.material(p).model]
        F, sig = model.update(params.phases[p.name], state.F[sl], state.stress[sl], L_mat[sl], dt)
        Fs.append(F)
        sigs.append(sig)
    F, sig = jnp.concatenate(Fs), jnp.concatenate(sigs)
    vol = state.volume * jnp.exp(dt * rate)
    D = 0.5 * (L + jnp.swapaxes(L, 1, 2))
    sig_f = 0.5 * (force_stress(lay, params, state) + force_stress(lay, params, replace(state, stress=sig)))
    power = jnp.sum(sig_f * D, axis=(1, 2)) * 0.5 * (vol + state.volume)
    energy = state.energy + dt * power / state.mass
    return F, sig, vol, energy
