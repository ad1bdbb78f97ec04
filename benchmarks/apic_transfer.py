"""The APIC step with its two transfer forms: forward and gradient time per step.

  offset    jaxmpm's APIC step (`step.apic_update`): `transfer.scatter_by_offset` /
            `gather_by_offset`, a loop over the 3^d stencil offsets with particles on the minor axis.
  stencil   the same step written with `shapes.Stencil` and the (N, S, C) `transfer.scatter` /
            `gather` (jaxmpm's APIC step before the offset loop; kept here as the reference).

Scene: the peers' mpm88 fluid (`jaxmpm.load_scene("mpm88")`), float32, the peers' dt. Forward: a
`lax.scan` of `steps` steps; gradient: `jax.value_and_grad` of the mean squared height after those
steps with respect to a uniform velocity offset (reverse mode through every step). Both forms are
compiled with `jaxmpm.jit`; their runs are interleaved (form by form, --repeats rounds) so that
machine noise hits both alike; the table gives the fastest and the median run.

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

HERE = Path(__file__).resolve().parent


def stencil_apic_update(lay, params, state, dt):
    """Reference: the APIC step with (N, S, C) transfers (same physics as step.apic_update)."""
    from jaxmpm import fields
    from jaxmpm.constitutive import constitutive
    from jaxmpm.shapes import stencil
    from jaxmpm.step import _apply_bc, _mass_floor, body_acceleration
    from jaxmpm.transfer import gather, scatter, stencil_apply, stencil_outer

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
    g = scatter(st, lay.field, jnp.concatenate([st.w[..., None] * m[:, None, None], mom], -1), lay.n_fields, lay.n_nodes)
    v_n = _apply_bc(lay, fields.safe_div(g[..., 1:], g[..., :1], m_min))
    vs = gather(st, lay.field, v_n)
    v = jnp.sum(st.w[..., None] * vs, 1)
    C = dinv * stencil_outer(st.w[..., None] * vs, st.dpos)
    moved = dataclasses.replace(state, x=state.x + dt * v, v=v, C=C)
    return dataclasses.replace(moved, t=state.t + dt, **constitutive(lay, params, moved, C, dt))


def programs(dim, n_grid, steps):
    import jaxmpm
    from jaxmpm.step import Layout

    scene = jaxmpm.load_scene("mpm88", n_grid=n_grid, dim=dim)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    dt = 2e-4 * 128 / n_grid if dim == 2 else 2e-4 * 64 / n_grid
    lay = Layout.of(scene)
    steppers = {"offset": jaxmpm.make_step(scene),
                "stencil": lambda p, s, dt: stencil_apic_update(lay, p, s, jnp.asarray(dt, s.t.dtype))}
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
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    ap.add_argument("--n-grid", type=int, default=None, help="cells per axis (default 128 in 2D, 48 in 3D)")
    ap.add_argument("--steps", type=int, default=None, help="steps per run (default 50 in 2D, 10 in 3D)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    n_grid = a.n_grid or (128 if a.dim == 2 else 48)
    steps = a.steps or (50 if a.dim == 2 else 10)
    progs, args, n = programs(a.dim, n_grid, steps)
    for f in progs.values():                                  # warm up
        jax.block_until_ready(f(*args))
    times = {k: [] for k in progs}
    for _ in range(a.repeats):
        for k, f in progs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(*args))
            times[k].append(time.perf_counter() - t0)
    rows = []
    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    for (form, kind), ts in times.items():
        best, med = min(ts) / steps, statistics.median(ts) / steps
        rows.append(dict(form=form, kind=kind, dim=a.dim, n_grid=n_grid, particles=n, steps=steps,
                         ms_per_step_min=1e3 * best, ms_per_step_median=1e3 * med,
                         mpart_steps_per_s=n / best / 1e6, device=str(jax.devices()[0]), cpu_count=os.cpu_count(),
                         jax_version=jax.__version__, date=stamp))
    by = {(r["form"], r["kind"]): r for r in rows}
    print(f"APIC step, mpm88 {a.dim}D {n_grid}^{a.dim}, {n} particles, float32, {steps} steps per run, "
          f"{a.repeats} interleaved runs")
    print(f"{'form':8s} {'kind':9s} {'ms/step min':>12s} {'median':>8s} {'Mpart-steps/s':>14s}")
    for r in rows:
        print(f"{r['form']:8s} {r['kind']:9s} {r['ms_per_step_min']:12.3f} {r['ms_per_step_median']:8.3f} "
              f"{r['mpart_steps_per_s']:14.2f}")
    for form in ("offset", "stencil"):
        print(f"{form}: gradient / forward = {by[(form, 'gradient')]['ms_per_step_min'] / by[(form, 'forward')]['ms_per_step_min']:.2f}")
    for kind in ("forward", "gradient"):
        print(f"{kind}: stencil / offset = {by[('stencil', kind)]['ms_per_step_min'] / by[('offset', kind)]['ms_per_step_min']:.2f}")
    out = Path(a.out) if a.out else HERE / "results" / f"apic_transfer_{a.dim}d.csv"
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
