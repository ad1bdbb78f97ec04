"""make_step(scene): the explicit MPM step composed from the stages the scene calls for.

    step(params, state, t_stop=inf, dt=None) -> state      (pure; jit, vmap and grad compose)

Stages (PHYSICS 2.1, ARCHITECTURE): 1 shape functions, 2 particle to grid, 3 grid update,
4 grid to particle with the seed's update and remap (or APIC), 5 constitutive update per phase.
Everything an effect needs is chosen here, in Python, before tracing: an effect the scene does not
name (gravity, damping, body force, DDMP, a wall) is not in the traced program at all. The
coupling of velocity fields (E3, E6, E7, E13, E15) is in jaxmpm.stages.multifield, stage 4 (grid to
particle) in jaxmpm.stages.grid_to_particle; the nodal quantities
the stages share (scatters, stress force parts, DDMP operators) in jaxmpm.stages.nodal.
"""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp

from jaxmpm.stages import fields
from jaxmpm.stages.grid_to_particle import grid_to_particle
from jaxmpm.stages.layout import Layout, apply_walls, wall_acceleration
from jaxmpm.stages.closure import force_stress
from jaxmpm.stages.constitutive import constitutive
from jaxmpm.stages.phase_models import bulk_modulus_and_wave_speed
from jaxmpm.stages.multifield import (
    exchange_force,
    interface_force,
    phase_pressure_and_compressibility,
    pressure_moments,
)
from jaxmpm.stages.nodal import (
    GridUpdate,
    ddmp_operators,
    nodal_stress_force,
    particle_radius,
    scatter_named,
    stress_parts,
)
from jaxmpm.numerics.forms import transfer_form
from jaxmpm.numerics.shapes import bspline2_stencil, ddmp_beta, stencil
from jaxmpm.numerics.transfer import (
    gather,
    gather_by_offset,
    offset_stencil,
    scatter,
    scatter_by_window,
    stencil_apply,
    stencil_outer,
)


@jax.custom_jvp
def tangent_fenced(x, on):
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


def _mass_floor(lay, state):
    eps = jnp.finfo(state.mass.dtype).eps
    return lay.particle_max(state.mass) * eps**2


def gravity_now(params, t):
    """Gravity (d,) at time t, ramped smoothly over params.gravity_ramp: g (1 - cos(pi t / T)) / 2."""
    T = params.gravity_ramp
    on = T > 0
    r = 0.5 * (1 - jnp.cos(jnp.pi * jnp.clip(t / jnp.where(on, T, 1.0), 0.0, 1.0)))
    return params.gravity * jnp.where(on, r, 1.0)


def wave_speed(scene, params, state):
    """(N,) longitudinal wave speed of every particle (m/s) at its current density."""
    return bulk_modulus_and_wave_speed(Layout.of(scene), params, state)[1]


def cfl_time_step(scene, params, state, cfl=None):
    """dt = CFL h / max_p (c_p + |v_p|) (PHYSICS 2.1), s."""
    return _cfl_time_step(Layout.of(scene), params, state, cfl)


def _cfl_time_step(lay, params, state, cfl=None):
    cfl = params.cfl if cfl is None else cfl
    v2 = jnp.sum(state.v * state.v, axis=-1)
    moving = v2 > 0
    speed = bulk_modulus_and_wave_speed(lay, params, state)[1] + jnp.where(
        moving, jnp.sqrt(jnp.where(moving, v2, 1.0)), 0.0
    )  # finite grad at rest
    return cfl * lay.scene.grid.h / lay.particle_max(speed)


# ----------------------------------------------------------------------------------- stages
# Each stage of the step runs under a jax.named_scope of its name in STAGES, and the parts of the
# grid update and of the grid-to-particle stage under those in STAGE_PARTS (where the scene has
# them): XLA's operations carry the names in their metadata, so that a profile can put its
# kernels' times on the stages (benchmarks/profile_step.py). The names change no computation.
STAGES = ("1_shape_functions", "2_particle_to_grid", "3_grid_update", "4_grid_to_particle", "5_constitutive")
STAGE_PARTS = ("ddmp_operators", "stress_force", "interface_force", "exchange", "remap", "velocity_gradient")


def body_acceleration(lay, params, state):
    """(N, d) per-particle body acceleration from gravity and per-phase body forces (m/s^2), or None."""
    scene = lay.scene
    acc = None
    if scene.gravity is not None:
        acc = jnp.broadcast_to(gravity_now(params, state.t), state.v.shape)
    if scene.body_force:
        b = jnp.concatenate(
            [
                jnp.broadcast_to(params.body_force[p.name], (sl.stop - sl.start, lay.dim))
                for p, sl in zip(scene.phases, lay.slices)
            ]
        )
        acc = b if acc is None else acc + b
    return acc


def particle_to_grid(lay, params, st, state, beta):
    """Stage 2: one scatter of mass, momentum and stress force for all fields, plus what DDMP
    (nodal volume, stress share) and the multi-field stage (compressibility; E15's fit moments,
    which the continuity form scatters in `multifield.interface_force` instead) need.
    Returns {name: (K, n_nodes, C)}."""
    m, v, V = state.mass, state.v, state.volume
    w = st.w[..., None]
    parts = {"m": w * m[:, None, None], "mv": w * (m[:, None] * v)[:, None, :]}
    parts.update(stress_parts(st, V, beta, force_stress(lay, params, state), particle_radius(lay, state)))
    if beta is not None or lay.n_fields > 1:
        parts["vol"] = w * V[:, None, None]
    if lay.scene.has_interface_forces:
        p, kappa = phase_pressure_and_compressibility(lay, params, state)
        if lay.scene.continuity_form != "transport":
            parts["pm"] = pressure_moments(lay, st, p, V)  # (E15)
        parts["kvol"] = w * (V * kappa)[:, None, None]
    return scatter_named(lay, st, parts)


def grid_acceleration(lay, params, state, st, beta, g, acc_p, dt, m_min):
    """Stage 3: nodal velocity v_old (walls applied) and acceleration a (K, n_nodes, d):
    internal force (E11), interface forces (E13), body forces, damping, implicit exchange (E3).
    Returns a `GridUpdate`: v_old, a, the DDMP operators or None, the closure's ambient pressure
    (K, n_nodes) where every field holds one phase and the fields have interface forces (else None:
    `grid_to_particle` forms it per phase, E8), the continuity form's volume rate v -> (N,)
    (`multifield.interface_force`) or None, the exchange's pair impulses (P, n_nodes, d) in N s
    with scene.drag_heating (`fields.exchange`), else None."""
    scene = lay.scene
    dtype = state.mass.dtype
    dg = None
    if beta is not None or scene.has_interface_forces:
        with jax.named_scope("ddmp_operators"):
            dg = ddmp_operators(lay, st, g["vol"][..., 0], dtype, state.volume)
    m = g["m"]
    v = apply_walls(lay, fields.safe_div(g["mv"], m, m_min))
    with jax.named_scope("stress_force"):
        f = nodal_stress_force(lay, dg, g)
    p_amb, volume_rate = None, None
    if scene.has_interface_forces:
        with jax.named_scope("interface_force"):
            I, p_amb, volume_rate = interface_force(lay, params, st, beta, state, g, dg, m_min)
        f = f + I
    if acc_p is not None:
        f = f + lay.particle_sum(
            scatter(
                st, lay.field, st.w[..., None] * (state.mass[:, None] * acc_p)[:, None, :], lay.n_fields, lay.n_nodes
            )
        )
    a = fields.safe_div(f, m, m_min)
    if scene.damping is not None:
        a = a - params.damping * v
    a = wall_acceleration(lay, v, a, dt)
    impulses = None
    if scene.has_exchange:
        with jax.named_scope("exchange"):
            F = exchange_force(lay, params, m[..., 0], g["vol"][..., 0], v + dt * a, dt, m_min, scene.drag_heating)
            if scene.drag_heating:
                F, impulses = F
        a = wall_acceleration(lay, v, a + fields.safe_div(F, m, m_min), dt)
    return GridUpdate(v, a, dg, p_amb, volume_rate, impulses)


def seed_update(lay, params, state, dt):
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
    scene = lay.scene
    m_min = _mass_floor(lay, state)
    with jax.named_scope(STAGES[0]):  # 1
        st = stencil(scene, state.x)
        beta = ddmp_beta(st.xi) if scene.shape == "ddmp" else None
    with jax.named_scope(STAGES[1]):  # 2
        g = particle_to_grid(lay, params, st, state, beta)
        if lay.n_fields == 1:
            # the nodal parts' cotangent as one array: XLA had fused its computation (about 130
            # operations per node) into the transposed scatter's gather, repeated per particle and
            # stencil node. One field: gradients 0.86-1.00 of the time before (elastic impact,
            # Taylor bars, 1D bars, interleaved); two fields 1.01-1.07, where the cotangent's computation
            # moved into the DDMP operators' transposes (benchmarks/NOTES.md, Gradients)
            g = tangent_fenced(g, dt > 0)
        acc_p = body_acceleration(lay, params, state)
    with jax.named_scope(STAGES[2]):  # 3
        grid = grid_acceleration(lay, params, state, st, beta, g, acc_p, dt, m_min)
    with jax.named_scope(STAGES[3]):  # 4
        moved, L, p_amb = grid_to_particle(lay, params, state, st, beta, g, grid, dt, m_min)
    with jax.named_scope(STAGES[4]):  # 5
        # L's cotangent as one array: XLA had fused its computation from the constitutive
        # update's transpose into each consumer in the velocity gradient's transpose, repeated per
        # stencil node (that stage's transpose: 8.8 -> 2.0-2.6 forward runs of it, benchmarks/NOTES.md)
        new = constitutive(lay, params, moved, tangent_fenced(L, dt > 0), dt, p_amb)
    return replace(moved, t=state.t + dt, **new)


def apic_update(lay, params, state, dt):
    """APIC / MLS-MPM step with quadratic B-splines (D^-1 = 4 / h^2), for the peers' scene. One
    velocity field (Scene checks it). Transfers in the form of `forms.transfer_form()`:
      "cpu"  the particle data component-major (particles last): the particle-to-grid transfer
             adds each particle's 3^d block of nodes in one windowed scatter of particle blocks
             (`transfer.scatter_by_window`), the grid-to-particle transfer loops over the 3^d
             stencil offsets (`transfer.gather_by_offset`);
      "gpu"  particles major, every stencil offset in one pass: one scatter-add of N x 3^d rows of
             mass and momentum, one gather of N x 3^d nodal velocities (`transfer.scatter`,
             `transfer.gather` on a `shapes.Stencil`)."""
    scene = lay.scene
    h = scene.grid.h
    dinv = 4.0 / h**2
    m_min = _mass_floor(lay, state)
    one_pass = transfer_form() == "gpu"
    with jax.named_scope(STAGES[0]):
        st = bspline2_stencil(scene.grid, state.x) if one_pass else offset_stencil(scene.grid, state.x, "bspline2")
    m, V = state.mass, state.volume
    with jax.named_scope(STAGES[1]):
        affine = (m[:, None, None] * state.C) - dt * dinv * V[:, None, None] * state.stress  # MLS force folded in
        mv = m[:, None] * state.v
        acc_p = body_acceleration(lay, params, state)
        if acc_p is not None:
            mv = mv + dt * m[:, None] * acc_p
        if one_pass:
            g = lay.particle_sum(_apic_scatter_one_pass(st, m, mv, affine, lay.n_nodes))  # (1, n_nodes, 1 + d)
        else:
            g = lay.particle_sum(_apic_scatter_by_window(st, m, mv, affine))[None]
    with jax.named_scope(STAGES[2]):
        v_n = fields.safe_div(g[..., 1:], g[..., :1], m_min)
        if scene.damping is not None:
            v_n = v_n * jnp.exp(-params.damping * dt)
        v_n = apply_walls(lay, v_n)  # (1, n_nodes, d)
    with jax.named_scope(STAGES[3]):
        v, B = _apic_gather_one_pass(st, v_n) if one_pass else _apic_gather_by_offset(st, v_n[0].T)
        C = dinv * B
        moved = replace(state, x=state.x + dt * v, v=v, C=C)
    with jax.named_scope(STAGES[4]):
        new = constitutive(lay, params, moved, C, dt)  # (Scene refuses the closure, E8, with APIC)
    return replace(moved, t=state.t + dt, **new)


def _apic_scatter_by_window(ost, m, mv, affine):
    """APIC's particle-to-grid sums (n_nodes, 1 + d) of mass w m and momentum
    w (m v + affine . (x_n - x_p)), by windowed scatter of particle blocks (the CPU form).
    m (N,) kg, mv (N, d) kg m/s, affine (N, d, d) kg/s."""
    d = mv.shape[-1]

    def contrib(w, dpos, m, mv, affine):
        return [w * m] + [w * (mv[c] + sum(affine[c, k] * dpos[k] for k in range(d))) for c in range(d)]

    return scatter_by_window(ost, contrib, (m, mv.T, jnp.transpose(affine, (1, 2, 0))), d + 1, m.dtype)


def _apic_scatter_one_pass(st, m, mv, affine, n_nodes):
    """`_apic_scatter_by_window`'s sums as one scatter-add of the (N, 3^d, 1 + d) rows of every
    particle's stencil (the GPU form): (1, n_nodes, 1 + d)."""
    w = st.w[..., None]
    rows = jnp.concatenate([w * m[:, None, None], w * (mv[:, None, :] + stencil_apply(affine, st.dpos))], -1)
    return scatter(st, None, rows, 1, n_nodes)


def _apic_gather_by_offset(ost, v_n):
    """APIC's grid-to-particle sums v = sum_n w v_n (N, d) and B = sum_n w v_n (x) (x_n - x_p)
    (N, d, d) from the nodal velocities v_n (d, n_nodes), in a loop over the stencil offsets (the
    CPU form)."""
    d, n = ost.fx.shape

    def accumulate(carry, w, dpos, vals):
        v, B = carry
        wv = w * vals
        return v + wv, B + wv[:, None] * dpos[None]

    v, B = gather_by_offset(ost, v_n, accumulate, (jnp.zeros_like(ost.fx), jnp.zeros_like(ost.fx, shape=(d, d, n))))
    return v.T, jnp.transpose(B, (2, 0, 1))


def _apic_gather_one_pass(st, v_n):
    """`_apic_gather_by_offset`'s sums from one gather of the (N, 3^d, d) nodal velocities of every
    particle's stencil (the GPU form); v_n (1, n_nodes, d)."""
    wv = st.w[..., None] * gather(st, None, v_n)
    return jnp.sum(wv, 1), stencil_outer(wv, st.dpos)


def make_step(scene, shards=1, axis_name=None):
    """Compose the pure step of `scene`: step(params, state, t_stop=inf, dt=None) -> state.

    t_stop and dt in s. dt defaults to the CFL step (PHYSICS 2.1); it is clipped so that t never passes t_stop, and a
    step with dt = 0 returns the state unchanged (so a fixed-length scan stays differentiable).
    shards, axis_name: the step of one device's block of particles when every phase's particles
    are split in `shards` equal parts along the mesh axis `axis_name` (run it under shard_map:
    `jaxmpm.distributed.make_sharded_step`); scatters are summed and particle maxima taken
    across that axis, the grid update is repeated on every device.
    """
    lay = Layout.of(scene, shards, axis_name)
    update = apic_update if scene.transfer == "apic" else seed_update

    def step(params, state, t_stop=jnp.inf, dt=None):
        dt = _cfl_time_step(lay, params, state) if dt is None else jnp.asarray(dt, state.t.dtype)
        dt = jnp.clip(jnp.minimum(dt, t_stop - state.t), 0.0, None)
        active = dt > 0
        new = update(lay, params, state, dt)
        return jax.tree.map(lambda a, b: jnp.where(active, a, b), new, state)

    return step
