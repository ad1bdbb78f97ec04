"""The APIC step with three transfer forms: forward and gradient time per step.

  window    jaxmpm's APIC step (`step.apic_update`): the particle-to-grid transfer as one windowed
            scatter of each particle's 3^d node block, particles in blocks of 8 on the minor axis
            (`transfer.scatter_by_window`); grid to particle by `transfer.gather_by_offset`.
  offset    the same step with `transfer.scatter_by_offset` (a loop over the 3^d stencil offsets,
            one scatter of rows per offset, particles on the minor axis) for the particle-to-grid
            transfer (jaxmpm's APIC step before the windowed scatter; kept here as a reference).
  stencil   the same step written with `shapes.Stencil` and the (N, S, C) `transfer.scatter` /
            `gather` (jaxmpm's APIC step before the offset loop; kept here as the reference).

Scene: the peers' mpm88 fluid (`jaxmpm.load_scene("mpm88")`), float32, the peers' dt. Forward: a
`lax.scan` of `steps` steps; gradient: `jax.value_and_grad` of the mean squared height after those
steps with respect to a uniform velocity offset (reverse mode through every step). All forms are
compiled with `jaxmpm.jit`; their runs are interleaved (form by form, --repeats rounds) so that
machine noise hits all alike, each timed run right after an untimed run of the same program (the
first run after another, larger program measured up to 2x slower: memory handed back and taken
again); the table gives the fastest and the median run.

    python benchmarks/apic_transfer.py [--dim 2] [--n-grid 128] [--steps 50] [--repeats 5]

Writes benchmarks/results/apic_transfer_{2d,3d}.csv (or --out).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import os
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py

HERE = Path(__file__).resolve().parent


def stencil_apic_update(lay, params, state, dt):
    """Reference: the APIC step with (N, S, C) transfers (same physics as step.apic_update)."""
    from jaxmpm.stages import fields
    from jaxmpm.stages.constitutive import constitutive
    from jaxmpm.numerics.shapes import stencil
    from jaxmpm.stages.layout import apply_walls as _apply_bc
    from jaxmpm.step import _mass_floor, body_acceleration
    from jaxmpm.numerics.transfer import gather, scatter, stencil_apply, stencil_outer

    scene = lay.scene
    dinv = 4.0 / scene.grid.h**2
    m_min = _mass_floor(lay, state)
    st = stencil(scene, state.x)
    m, V = state.mass, state.volume
    affine = (m[:, None, None] * state.C) - dt * dinv * V[:, None, None] * state.stress
    mom = st.w[..., None] * (m[:, None] * state.v)[:, None, :] + st.w[..., None] * stencil_apply(affine, st.dpos)
    acc_p = body_acceleration(lay, params, state)
    if acc_p is not None:
        mom = mom + dt * st.w[..., None] * (m[:, None] * acc_p)[:, None, :]
    g = scatter(
        st, lay.field, jnp.concatenate([st.w[..., None] * m[:, None, None], mom], -1), lay.n_fields, lay.n_nodes
    )
    v_n = _apply_bc(lay, fields.safe_div(g[..., 1:], g[..., :1], m_min))
    vs = gather(st, lay.field, v_n)
    v = jnp.sum(st.w[..., None] * vs, 1)
    C = dinv * stencil_outer(st.w[..., None] * vs, st.dpos)
    moved = dataclasses.replace(state, x=state.x + dt * v, v=v, C=C)
    return dataclasses.replace(moved, t=state.t + dt, **constitutive(lay, params, moved, C, dt))


def offset_apic_update(lay, params, state, dt):
    """Reference: the APIC step with the particle-to-grid transfer by `transfer.scatter_by_offset`
    (same physics as step.apic_update)."""
    from jaxmpm.stages import fields
    from jaxmpm.stages.constitutive import constitutive
    from jaxmpm.stages.layout import apply_walls as _apply_bc
    from jaxmpm.step import _mass_floor, body_acceleration
    from jaxmpm.numerics.transfer import gather_by_offset, offset_stencil, scatter_by_offset

    d, h = lay.dim, lay.scene.grid.h
    dinv = 4.0 / h**2
    m_min = _mass_floor(lay, state)
    ost = offset_stencil(lay.scene.grid, state.x, "bspline2")
    m, V = state.mass, state.volume
    affine = jnp.transpose((m[:, None, None] * state.C) - dt * dinv * V[:, None, None] * state.stress, (1, 2, 0))
    mv = m[:, None] * state.v
    acc_p = body_acceleration(lay, params, state)
    if acc_p is not None:
        mv = mv + dt * m[:, None] * acc_p
    mv = mv.T

    def contrib(w, dpos):
        return jnp.concatenate([(w * m)[None], w * (mv + sum(affine[:, k] * dpos[k] for k in range(d)))], 0)

    g = scatter_by_offset(ost, contrib, d + 1, lay.n_nodes, m.dtype)[None]
    v_n = _apply_bc(lay, fields.safe_div(g[..., 1:], g[..., :1], m_min))[0].T

    def accumulate(carry, w, dpos, vals):
        return carry[0] + w * vals, carry[1] + (w * vals)[:, None] * dpos[None]

    n = m.shape[0]
    v, B = gather_by_offset(ost, v_n, accumulate, (jnp.zeros_like(ost.fx), jnp.zeros_like(ost.fx, shape=(d, d, n))))
    v, C = v.T, dinv * jnp.transpose(B, (2, 0, 1))
    moved = dataclasses.replace(state, x=state.x + dt * v, v=v, C=C)
    return dataclasses.replace(moved, t=state.t + dt, **constitutive(lay, params, moved, C, dt))


def programs(dim, n_grid, steps):
    import jaxmpm
    from jaxmpm.stages.layout import Layout

    scene = jaxmpm.load_scene("mpm88", n_grid=n_grid, dim=dim)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    dt = 2e-4 * 128 / n_grid if dim == 2 else 2e-4 * 64 / n_grid
    lay = Layout.of(scene)
    steppers = {
        "window": jaxmpm.make_step(scene),
        "offset": lambda p, s, dt: offset_apic_update(lay, p, s, jnp.asarray(dt, s.t.dtype)),
        "stencil": lambda p, s, dt: stencil_apic_update(lay, p, s, jnp.asarray(dt, s.t.dtype)),
    }
    out = {}
    for form, step in steppers.items():

        def rollout(v0, params, state, step=step):
            s = dataclasses.replace(state, v=state.v + v0)
            return jax.lax.scan(lambda c, _: (step(params, c, dt=dt), None), s, None, length=steps)[0]

        def loss(v0, params, state, rollout=rollout):
            return jnp.mean(rollout(v0, params, state).x[:, 1] ** 2)

        v0 = jnp.zeros(dim, state.x.dtype)
        out[(form, "forward")] = jaxmpm.jit(rollout).lower(v0, params, state).compile()
        out[(form, "gradient")] = jaxmpm.jit(jax.value_and_grad(loss)).lower(v0, params, state).compile()
    return out, (jnp.zeros(dim, state.x.dtype), params, state), state.x.shape[0]


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    ap.add_argument("--n-grid", type=int, default=None, help="cells per axis (default 128 in 2D, 48 in 3D)")
    ap.add_argument("--steps", type=int, default=None, help="steps per run (default 50 in 2D, 10 in 3D)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=None)
    add_overwrite(ap)
    a = ap.parse_args()
    out = Path(a.out) if a.out else HERE / "results" / f"apic_transfer_{a.dim}d.csv"
    check_outputs(out, overwrite=a.overwrite)
    n_grid = a.n_grid or (128 if a.dim == 2 else 48)
    steps = a.steps or (50 if a.dim == 2 else 10)
    progs, args, n = programs(a.dim, n_grid, steps)
    for f in progs.values():  # warm up
        jax.block_until_ready(f(*args))
    times = {k: [] for k in progs}
    for _ in range(a.repeats):
        for k, f in progs.items():
            jax.block_until_ready(f(*args))  # untimed: the first run after another program's
            t0 = time.perf_counter()  # (whose buffers were freed) can be 2x slower
            jax.block_until_ready(f(*args))
            times[k].append(time.perf_counter() - t0)
    rows = []
    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    for (form, kind), ts in times.items():
        best, med = min(ts) / steps, statistics.median(ts) / steps
        rows.append(
            dict(
                form=form,
                kind=kind,
                dim=a.dim,
                n_grid=n_grid,
                particles=n,
                steps=steps,
                ms_per_step_min=1e3 * best,
                ms_per_step_median=1e3 * med,
                mpart_steps_per_s=n / best / 1e6,
                device=describe(),
                cpu_count=os.cpu_count(),
                jax_version=jax.__version__,
                date=stamp,
            )
        )
    by = {(r["form"], r["kind"]): r for r in rows}
    print(
        f"APIC step, mpm88 {a.dim}D {n_grid}^{a.dim}, {n} particles, float32, {steps} steps per run, "
        f"{a.repeats} interleaved runs"
    )
    print(f"{'form':8s} {'kind':9s} {'ms/step min':>12s} {'median':>8s} {'Mpart-steps/s':>14s}")
    for r in rows:
        print(
            f"{r['form']:8s} {r['kind']:9s} {r['ms_per_step_min']:12.3f} {r['ms_per_step_median']:8.3f} "
            f"{r['mpart_steps_per_s']:14.2f}"
        )
    for form in ("window", "offset", "stencil"):
        print(
            f"{form}: gradient / forward = {by[(form, 'gradient')]['ms_per_step_min'] / by[(form, 'forward')]['ms_per_step_min']:.2f}"
        )
    for kind in ("forward", "gradient"):
        for form in ("offset", "stencil"):
            print(
                f"{kind}: {form} / window = {by[(form, kind)]['ms_per_step_min'] / by[('window', kind)]['ms_per_step_min']:.2f}"
            )
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
