"""The APIC / MLS-MPM step with quadratic B-splines (transfer = 'apic'), for the peers' scene:
its stages 1-4 (stage 5 is jaxmpm.stages.constitutive's), in the transfer form of the machine
(`jaxmpm.numerics.forms.transfer_form`).

Shapes: N particles, n nodes, d dimensions; SI units.
"""

from __future__ import annotations

from jaxmpm.model.params import Params
from jaxmpm.model.state import State
from jaxmpm.stages.layout import Layout

from dataclasses import replace

import jax
import jax.numpy as jnp

from jaxmpm.numerics.forms import transfer_form
from jaxmpm.numerics.shapes import bspline2_stencil
from jaxmpm.numerics.transfer import (
    gather,
    gather_by_offset,
    offset_stencil,
    scatter,
    scatter_by_window,
    stencil_apply,
    stencil_outer,
)
from jaxmpm.stages import fields
from jaxmpm.stages.ambient import gauge_stress
from jaxmpm.stages.constitutive import constitutive
from jaxmpm.stages.layout import STAGES, apply_walls, mass_floor
from jaxmpm.stages.particle_to_grid import body_acceleration


def apic_update(layout: Layout, params: Params, state: State, dt: jax.Array) -> State:
    """APIC / MLS-MPM step with quadratic B-splines (D^-1 = 4 / h^2), for the peers' scene. One
    velocity field (Scene checks it). Transfers in the form of `forms.transfer_form()`:
      "cpu"  the particle data component-major (particles last): the particle-to-grid transfer
             adds each particle's 3^d block of nodes in one windowed scatter of particle blocks
             (`transfer.scatter_by_window`), the grid-to-particle transfer loops over the 3^d
             stencil offsets (`transfer.gather_by_offset`);
      "gpu"  particles major, every stencil offset in one pass: one scatter-add of N x 3^d rows of
             mass and momentum, one gather of N x 3^d nodal velocities (`transfer.scatter`,
             `transfer.gather` on a `shapes.Stencil`)."""
    scene = layout.scene
    h = scene.grid.h
    dinv = 4.0 / h**2
    m_min = mass_floor(layout, state)
    one_pass = transfer_form() == "gpu"
    with jax.named_scope(STAGES[0]):
        stencils = (
            bspline2_stencil(scene.grid, state.x) if one_pass else offset_stencil(scene.grid, state.x, "bspline2")
        )
    m, V = state.mass, state.volume
    with jax.named_scope(STAGES[1]):
        sig = gauge_stress(layout, params, state.stress)
        affine = (m[:, None, None] * state.C) - dt * dinv * V[:, None, None] * sig  # MLS force folded in
        mv = m[:, None] * state.v
        acc_p = body_acceleration(layout, params, state)
        if acc_p is not None:
            mv = mv + dt * m[:, None] * acc_p
        if one_pass:
            sums = layout.particle_sum(
                _apic_scatter_one_pass(stencils, m, mv, affine, layout.n_nodes)
            )  # (1, n_nodes, 1 + d)
        else:
            sums = layout.particle_sum(_apic_scatter_by_window(stencils, m, mv, affine))[None]
    with jax.named_scope(STAGES[2]):
        v_n = fields.safe_div(sums[..., 1:], sums[..., :1], m_min)
        if scene.damping is not None:
            v_n = v_n * jnp.exp(-params.damping * dt)
        v_n = apply_walls(layout, v_n)  # (1, n_nodes, d)
    with jax.named_scope(STAGES[3]):
        v, B = _apic_gather_one_pass(stencils, v_n) if one_pass else _apic_gather_by_offset(stencils, v_n[0].T)
        C = dinv * B
        moved = replace(state, x=state.x + dt * v, v=v, C=C)
    with jax.named_scope(STAGES[4]):
        new = constitutive(layout, params, moved, C, dt)  # (Scene refuses the closure, E8, with APIC)
    return replace(moved, t=state.t + dt, **new._asdict())


def _apic_scatter_by_window(offset_stencils, m, mv, affine):
    """APIC's particle-to-grid sums (n_nodes, 1 + d) of mass w m and momentum
    w (m v + affine . (x_n - x_p)), by windowed scatter of particle blocks (the CPU form).
    m (N,) kg, mv (N, d) kg m/s, affine (N, d, d) kg/s."""
    d = mv.shape[-1]

    def contrib(w, dpos, m, mv, affine):
        return [w * m] + [w * (mv[c] + sum(affine[c, k] * dpos[k] for k in range(d))) for c in range(d)]

    return scatter_by_window(offset_stencils, contrib, (m, mv.T, jnp.transpose(affine, (1, 2, 0))), d + 1, m.dtype)


def _apic_scatter_one_pass(stencils, m, mv, affine, n_nodes):
    """`_apic_scatter_by_window`'s sums as one scatter-add of the (N, 3^d, 1 + d) rows of every
    particle's stencil (the GPU form): (1, n_nodes, 1 + d)."""
    w = stencils.w[..., None]
    rows = jnp.concatenate([w * m[:, None, None], w * (mv[:, None, :] + stencil_apply(affine, stencils.dpos))], -1)
    return scatter(stencils, None, rows, 1, n_nodes)


def _apic_gather_by_offset(offset_stencils, v_n):
    """APIC's grid-to-particle sums v = sum_n w v_n (N, d) and B = sum_n w v_n (x) (x_n - x_p)
    (N, d, d) from the nodal velocities v_n (d, n_nodes), in a loop over the stencil offsets (the
    CPU form)."""
    d, n = offset_stencils.fx.shape

    def accumulate(carry, w, dpos, vals):
        v, B = carry
        wv = w * vals
        return v + wv, B + wv[:, None] * dpos[None]

    v, B = gather_by_offset(
        offset_stencils,
        v_n,
        accumulate,
        (jnp.zeros_like(offset_stencils.fx), jnp.zeros_like(offset_stencils.fx, shape=(d, d, n))),
    )
    return v.T, jnp.transpose(B, (2, 0, 1))


def _apic_gather_one_pass(stencils, v_n):
    """`_apic_gather_by_offset`'s sums from one gather of the (N, 3^d, d) nodal velocities of every
    particle's stencil (the GPU form); v_n (1, n_nodes, d)."""
    wv = stencils.w[..., None] * gather(stencils, None, v_n)
    return jnp.sum(wv, 1), stencil_outer(wv, stencils.dpos)
