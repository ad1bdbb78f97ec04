"""Stage 5 of the step: the constitutive update of every phase by its model kind, the material
volume rate with the continuous-to-disperse closure (E4, E5, E8), artificial viscosity and the
internal energy.

Shapes: N particles, d dimensions; SI units.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.materials.models import MatPoint, model_of, split_model, MODELS


def fails(model_name) -> bool:
    """Whether a model kind has a failure part (a hydrocode composite with spall, Johnson-Cook
    failure, ...) or is a one-piece kind that sets damage (maxwell_brittle)."""
    if model_name in MODELS:
        return MODELS[model_name].can_fail
    return bool(split_model(model_name)[2])


def fragmentation_gate(lay, state):
    """(N,) the factor G of alpha = 1 - G tanh(eps_ps / C_h): with scene.fragmentation 'failed',
    the damage D of particles whose phase can fail and 1 for the others; with 'plastic', 1.

    Why 'failed' is the default (our choice; the seed's E5 counts all plastic strain): a shock
    gives intact metal plastic strains of 0.1 - 0.5, so with C_h = 0.02 the seed's alpha fell to ~0
    inside the shock; the fragmented part then relaxes toward the ambient pressure (E8) and pushes
    with alpha p only, so the shock died in the plate. On the debris cloud at resolution 1 (one
    field, C_h = 0.02) points 1, 2, 4 came out at 5.33, 5.33, 6.10 km/s with 'plastic' against
    5.96, 6.09, 4.87 with 'failed' and 5.97, 6.00, 4.87 with no closure (experiment 6.3, 6.1, 3.9)."""
    scene = lay.scene
    if scene.fragmentation == "plastic":
        return jnp.ones_like(state.eps_ps)
    gated = np.concatenate(
        [np.full(sl.stop - sl.start, fails(scene.material(p).model), bool) for p, sl in zip(scene.phases, lay.slices)]
    )
    if not gated.any():
        return jnp.ones_like(state.eps_ps)
    return jnp.where(jnp.asarray(gated), state.damage, 1.0)


def closure_alpha(lay, params, state):
    """(E5) alpha = 1 - G tanh(eps_ps / C_h): 1 for intact material, -> 0 when fragmented; G the
    fragmentation gate (damage of phases that can fail, else 1: `fragmentation_gate`). With
    fragmentation 'tensile', alpha = 1 - D, D = tanh(eps_t / C_h) the fragmented fraction that the
    State's damage holds (`tensile_fragment_fraction`). (N,)"""
    if lay.scene.fragmentation == "tensile":
        return 1.0 - state.damage
    return 1.0 - fragmentation_gate(lay, state) * jnp.tanh(state.eps_ps / params.c_h)


def pressure_factor(lay, params, state):
    """(N,) the factor a of the particle pressure in the closure's grid force, common pressure and
    volume rate (E4, E8): alpha, except with fragmentation 'tensile', where a = alpha only in
    tension (p < 0) and 1 in compression: fragments in contact carry compression, not tension."""
    alpha = closure_alpha(lay, params, state)
    if lay.scene.fragmentation == "tensile":
        return jnp.where(pressure(lay, state) < 0, alpha, 1.0)
    return alpha


def tanh_sum(a, b):
    """tanh(atanh(a) + atanh(b)) = (a + b) / (1 + a b), for a, b in [0, 1]."""
    return (a + b) / (1.0 + a * b)


def tensile_fragment_fraction(c_h, damage, counted):
    """(E5, fragmentation 'tensile') the fragmented fraction D = tanh(eps_t / C_h) after the
    counted plastic strain increment `counted` (>= 0) from D = `damage`: exactly
    tanh(atanh(D) + counted / C_h), in the form that needs no atanh (finite at D = 1). (N,)"""
    return tanh_sum(damage, jnp.tanh(counted / c_h))


def tension_mask(lay, state):
    """(N,) 1.0 where this step's plastic strain counts toward fragmentation (fragmentation
    'tensile'): where the particle is in tension at the step's start, p < 0 (p with the artificial
    viscosity, >= 0). A shock compresses (p > 0): its plastic strain never counts. Else 0.0."""
    return (pressure(lay, state) < 0).astype(state.mass.dtype)


def pressure(lay, state):
    """(N,) pressure of every particle, Pa: state.pressure for the hydrocode models (EOS plus
    artificial viscosity), -tr(stress) / d for the total-stress models (so a user who edits the
    stress of such a State needs not edit the pressure)."""
    scene = lay.scene
    if all(model_of(scene.material(p).model).hydro for p in scene.phases):
        return state.pressure
    tr = -jnp.trace(state.stress, axis1=1, axis2=2) / state.stress.shape[-1]
    return jnp.concatenate(
        [
            state.pressure[sl] if model_of(scene.material(p).model).hydro else tr[sl]
            for p, sl in zip(scene.phases, lay.slices)
        ]
    )


def force_stress(lay, params, state):
    """Stress whose divergence the grid sees (N, d, d): with the closure (E8) the pressure scaled by
    the closure's factor a (`pressure_factor`), sigma + (1 - a) p I, so a fragmented material does
    no work through a volume change it does not have (p = state.pressure, the pressure the stress
    holds)."""
    if lay.scene.c_h is None:
        return state.stress
    d = state.stress.shape[-1]
    p = pressure(lay, state)
    return state.stress + ((1 - pressure_factor(lay, params, state)) * p)[:, None, None] * jnp.eye(
        d, dtype=state.stress.dtype
    )


def model_groups(lay):
    """The phases grouped by model kind, in order of first appearance: a tuple of (model name,
    phase indices, particles) with particles a slice where the group's particles are contiguous
    in particle order, else a static index array. Static (from the scene)."""
    scene = lay.scene
    names = [scene.material(p).model for p in scene.phases]
    groups = []
    for name in dict.fromkeys(names):
        members = tuple(i for i, n in enumerate(names) if n == name)
        idx = np.concatenate([np.arange(lay.slices[i].start, lay.slices[i].stop) for i in members])
        contiguous = idx.size == 0 or np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size))
        groups.append((name, members, slice(int(idx[0]), int(idx[0]) + idx.size) if contiguous and idx.size else idx))
    return tuple(groups)


def per_model(lay, params, fn, *arrays):
    """fn(model, constants, *arrays) -> pytree of (n, ...) arrays, evaluated once per model kind
    on that kind's particles and assembled in particle order. arrays: (N, ...) per-particle
    inputs (or None, passed through). fn is written for scalar constants: for a kind shared by
    several phases, their constants become per-particle arrays and fn runs under jax.vmap with
    each particle as a batch of one.

    Why: on the CPU the per-particle updates are dozens of small kernels each, and their cost is
    mostly per kernel: two phases of one kind (a projectile and its target of the same metal, in
    separate velocity fields) ran every kernel twice on half the particles."""
    scene = lay.scene
    outs, order = [], []
    for name, members, part in model_groups(lay):
        if (part.stop - part.start if isinstance(part, slice) else part.size) == 0:
            continue
        model = model_of(name)
        args = [None if a is None else a[part] for a in arrays]
        if len(members) == 1:
            outs.append(fn(model, params.phases[scene.phases[members[0]].name], *args))
        else:
            sizes = [lay.slices[i].stop - lay.slices[i].start for i in members]
            consts = [params.phases[scene.phases[i].name] for i in members]
            c = {
                k: jnp.concatenate([jnp.broadcast_to(jnp.asarray(ci[k]), (n,)) for ci, n in zip(consts, sizes)])
                for k in consts[0]
                if all(k in ci for ci in consts)
            }  # the kind's constants: every phase has them
            present = [i for i, a in enumerate(args) if a is not None]

            def one(c, *xs, model=model, present=present, n_args=len(args)):  # noqa: B008 (bound at definition)
                full = [None] * n_args
                for i, x in zip(present, xs):
                    full[i] = x[None]
                return jax.tree.map(lambda y: y[0], fn(model, c, *full))

            outs.append(jax.vmap(one)(c, *(args[i] for i in present)))
        order.append(np.arange(part.start, part.stop) if isinstance(part, slice) else part)
    order = np.concatenate(order)
    joined = jax.tree.map(lambda *xs: jnp.concatenate(xs), *outs)
    if np.array_equal(order, np.arange(order.size)):
        return joined
    inverse = np.argsort(order)
    return jax.tree.map(lambda a: a[inverse], joined)


def bulk_modulus_and_wave_speed(lay, params, state):
    """(N,) bulk modulus K (Pa) and longitudinal wave speed c (m/s) at the particles' state.

    Failed material (damage D, 1 = failed) carries no shear, so its longitudinal speed loses the
    shear part: c^2 = K / rho + (1 - D)(c_model^2 - K / rho) for the hydrocode models, whose
    c_model^2 = K / rho + 4 G / (3 rho). Without it a failed particle expanded to 1e-4 of its
    density kept 4 G / (3 rho) ~ (500 km/s)^2 and the CFL step of the debris cloud collapsed."""
    rho = state.mass / state.volume
    dim = lay.scene.material_dim
    K, cw = per_model(
        lay,
        params,
        lambda m, c, r, e: (
            m.bulk_modulus(c, r, e, dim) * jnp.ones_like(r),
            m.wave_speed(c, r, e, dim) * jnp.ones_like(r),
        ),
        rho,
        state.energy,
    )
    hydro = np.concatenate(
        [
            np.full(sl.stop - sl.start, model_of(lay.scene.material(p).model).hydro, bool)
            for p, sl in zip(lay.scene.phases, lay.slices)
        ]
    )
    if hydro.any():
        cb2 = K / rho
        shear = jnp.maximum(cw * cw - cb2, 0.0)
        failed_speed = jnp.sqrt(cb2 + (1.0 - state.damage) * shear)
        cw = jnp.where(jnp.asarray(hydro), failed_speed, cw)
    return K, cw


EQUILIBRATING_STRAIN_MAX = 1.0  # |(p - p_amb) / K| bound of the closure (E8), log volume strain


def material_volume_rate(lay, params, state, L, dt, p_amb):
    """(E4) <div v_i> = alpha_i div<v_i> + B_i with (E5) alpha and the closure (E8)
    B_i = (1 - alpha_i)(p_i - p_amb) / (K_i tau_i), tau_i = h / c_i, taken as the exact exponential
    relaxation over the step, (1 - exp(-dt / tau)) / dt. p_amb: (N,) ambient pressure (Pa). (N,) 1/s.

    The ambient pressure is the common pressure (E6) of the OTHER phases at the particle, 0 Pa
    where none is present (vacuum), however the phases are grouped into velocity fields: from the
    interface forces' nodal quantities where every field holds one phase
    (`multifield.interface_force`), else from a scatter per phase
    (`multifield.ambient_pressure_by_phase`). Phases sharing a field, as in the
    one-field debris cloud, so relax toward each other's pressure, not 0 Pa: tests/test_closure.py
    runs the gas-filled case in one field and in two.

    (p_i - p_amb) / K_i is the linearised volumetric strain that brings p_i to p_amb. It is clipped
    to [-1, 1] (one e-fold of volume; our bound, not the seed's): far from the EOS's reference
    state (a failed, hot particle expanded to rho / rho0 ~ 1e-4, where K -> 0 while p stays
    finite) the linearisation asks for log-strains of hundreds in one step and the volume
    overflows. The bound never acts at the strains of the validation scenes (|p - p_amb| / K < 0.3
    in shocked aluminium at 6.7 km/s)."""
    alpha = pressure_factor(lay, params, state)
    K, c = bulk_modulus_and_wave_speed(lay, params, state)
    tau = lay.scene.grid.h / c
    x = dt / tau
    relax = jnp.where(x > 1e-8, -jnp.expm1(-x) / jnp.where(x > 1e-8, x, 1.0), 1.0) / tau
    strain = jnp.clip((pressure(lay, state) - p_amb) / K, -EQUILIBRATING_STRAIN_MAX, EQUILIBRATING_STRAIN_MAX)
    B = (1 - alpha) * strain * relax
    return alpha * jnp.trace(L, axis1=1, axis2=2) + B


def artificial_viscosity(lay, params, state, rho_new, trD):
    """von Neumann-Richtmyer pressure q = rho l (c_q l (tr D)^2 - c_l c tr D) in compression
    (tr D < 0), 0 in expansion; l the cell size h, c the bulk sound speed. (N,) Pa"""
    K, _ = bulk_modulus_and_wave_speed(lay, params, state)
    c = jnp.sqrt(K / (state.mass / state.volume))
    l = lay.scene.grid.h
    comp = jnp.minimum(trD, 0.0)
    return rho_new * l * (params.av_quadratic * l * comp**2 - params.av_linear * c * comp)


def viscous_particles(lay):
    """(N,) static bool: whether each particle's phase takes the artificial viscosity
    (scene.viscous_phases)."""
    return np.concatenate(
        [np.full(sl.stop - sl.start, on, bool) for on, sl in zip(lay.scene.viscous_phases, lay.slices)]
    )


def constitutive(lay, params, state, L, dt, p_amb=None):
    """Stage 5: volume V *= exp(dt tr L) (or the material rate of the closure, E4); per phase, its
    model's update of F, stress, pressure, internal energy (de = dt V_mid sigma_f:D / m with midpoint
    values, sigma_f the stress the grid sees), plastic strain and damage. Returns the new fields as a
    dict of State field names."""
    scene = lay.scene
    d = L.shape[-1]
    L_mat, rate = L, jnp.trace(L, axis1=1, axis2=2)
    carried = rate  # the volume rate the velocity field imposes on the material (E4's a div<v>)
    gate = None
    D = 0.5 * (L + jnp.swapaxes(L, 1, 2))
    tensile = scene.c_h is not None and scene.fragmentation == "tensile"
    if scene.c_h is not None:
        p_amb = jnp.zeros_like(state.mass) if p_amb is None else p_amb
        rate = material_volume_rate(lay, params, state, L, dt, p_amb)
        carried = pressure_factor(lay, params, state) * jnp.trace(L, axis1=1, axis2=2)
        L_mat = L + ((rate - jnp.trace(L, axis1=1, axis2=2)) / d)[:, None, None] * jnp.eye(d, dtype=L.dtype)
        gate = tension_mask(lay, state) if tensile else fragmentation_gate(lay, state)
    vol = state.volume * jnp.exp(dt * rate)
    rho_new = state.mass / vol
    q = None
    if scene.viscosity is not None:
        # q damps the velocity field's compression (a tr D, E4), not the closure's relaxation B (E8):
        # a fragment contracting to relieve its own tension is no shock. Driven by B, q turned
        # tensile fragments' pressure positive, the pressure's factor a to 1, and the fragments
        # pushed their neighbours with a pressure no velocity field compressed (docs/closure.md)
        q = artificial_viscosity(lay, params, state, rho_new, carried)
        if not all(scene.viscous_phases):
            q = jnp.where(jnp.asarray(viscous_particles(lay)), q, 0.0)
    work = dt * 0.5 * (vol + state.volume) / state.mass
    mp = MatPoint(
        state.F,
        state.stress,
        pressure(lay, state),
        state.energy,
        state.eps_ps,
        state.damage,
        state.mass / state.volume,
        rho_new,
    )

    def update(model, c, L_mat, D, work, q, gate, *mp):
        if gate is None:
            alpha_of = None
        elif tensile:
            m0 = MatPoint(*mp)

            def intact(eps):  # 1 - D after a plastic strain eps, counted where in tension
                return 1.0 - tensile_fragment_fraction(params.c_h, m0.damage, gate * jnp.maximum(eps - m0.eps_ps, 0.0))

            def alpha_of(eps):  # the pressure's factor: alpha in tension, 1 in compression
                return jnp.where(m0.pressure < 0, intact(eps), 1.0)
        else:  # the gate of the step's start: the damage the force and volume rate used
            alpha_of = lambda eps: 1.0 - gate * jnp.tanh(eps / params.c_h)
        return tuple(model.update(c, MatPoint(*mp), L_mat, D, dt, work, q, alpha_of))

    new = MatPoint(*per_model(lay, params, update, L_mat, D, work, q, gate, *mp))
    damage = new.damage
    if tensile:
        damage = tensile_fragment_fraction(params.c_h, damage, gate * jnp.maximum(new.eps_ps - state.eps_ps, 0.0))
    return dict(
        F=new.F,
        stress=new.stress,
        volume=vol,
        energy=new.energy,
        eps_ps=new.eps_ps,
        pressure=new.pressure,
        damage=damage,
    )
