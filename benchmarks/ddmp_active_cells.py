"""What per-field lists of active cells would save: DDMP's nodal velocity gradient (E12) on every
field's whole grid, as the step computes it (`ddmp.nodal_velocity_gradient`), against the same
operator on lists of the cells each field occupies (corners gathered, the per-cell contraction on
those cells alone, the corner sums scattered back onto the nodes). A measurement for the proposed
next step of the multi-field step, not a part of it: the lists here are fixed from the geometry
(a real step would rebuild them as the material moves, with a fixed capacity and an overflow check).

Geometry: the three blocks of benchmarks/multifield_cost.py on a 128^2 grid (each block's cells
plus a one-cell halo), as 3 fields, and the same cells as 1 field. Forward and reverse mode
(gradient of a scalar of the result with respect to the nodal velocities and the operators);
fastest of --repeats interleaved rounds. Prints a table and writes
benchmarks/results/ddmp_active_cells.csv.

    python benchmarks/ddmp_active_cells.py [--repeats 30]
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py

BOXES = (((0.40, 0.62), (0.60, 0.80)), ((0.20, 0.50), (0.80, 0.60)), ((0.20, 0.20), (0.80, 0.48)))


def field_masks(n, groups):
    """(K, n, n) bool: the cells of each field's blocks, with a one-cell halo."""
    masks = np.zeros((len(groups), n, n), bool)
    for k, members in enumerate(groups):
        for b in members:
            (lo, hi) = BOXES[b]
            a = [max(int(lo[i] * n) - 1, 0) for i in range(2)]
            e = [min(int(hi[i] * n) + 1, n) for i in range(2)]
            masks[k, a[0] : e[0], a[1] : e[1]] = True
    return masks


def case(n, groups, seed=0):
    """Inputs and both forms of the operator for one grouping of the blocks into fields."""
    from jaxmpm.numerics import ddmp
    from jaxmpm.model.scene import Grid
    from jaxmpm.numerics.shapes import stencil_offsets

    d = 2
    grid = Grid(cells=(n, n), h=1.0 / n)
    rng = np.random.default_rng(seed)
    masks = field_masks(n, groups)
    K = len(groups)
    offsets = stencil_offsets(d, 2)
    cv = np.zeros((K, n, n))
    nv = np.zeros((K, n + 1, n + 1))
    for k in range(K):
        cv[k][masks[k]] = grid.h**2 * rng.uniform(0.5, 1.0, masks[k].sum())
        for o in offsets:
            nv[k, o[0] : o[0] + n, o[1] : o[1] + n] += 0.25 * cv[k]
    dg = ddmp.build(grid, jnp.asarray(nv, jnp.float32), jnp.asarray(cv, jnp.float32))
    v = jnp.asarray(rng.normal(size=(K, n + 1, n + 1, d)), jnp.float32)
    cells = [np.argwhere(masks[k]) for k in range(K)]
    corner_nodes = [np.stack([(c[:, 0] + o[0]) * (n + 1) + c[:, 1] + o[1] for o in offsets], 1) for c in cells]
    A_active = [dg.A[k].reshape(n * n, 2**d, 2**d, d)[c[:, 0] * n + c[:, 1]] for k, c in enumerate(cells)]

    def whole_grid(v, A, V):
        return ddmp.nodal_velocity_gradient(grid, ddmp.DDMPGrid(V=V, A=A, theta=dg.theta), v)

    def active_cells(v, A_active, V):
        out = []
        for k in range(K):
            vc = v[k].reshape(-1, d)[corner_nodes[k]]  # (C, 2^d, d)
            Lc = sum(vc[:, None, i, :, None] * A_active[k][:, :, i, None, :] for i in range(2**d))  # (C, 2^d, d, d)
            out.append(
                jnp.zeros(((n + 1) ** 2, d, d), v.dtype).at[corner_nodes[k].reshape(-1)].add(Lc.reshape(-1, d, d))
            )
        L = jnp.stack(out).reshape(K, n + 1, n + 1, d, d)
        return ddmp.safe_div(L, V[..., None, None], 1e-12 * grid.h**d)

    return dict(
        fields=K,
        active_fraction=float(masks.mean()),
        grid_args=(v, dg.A, dg.V),
        list_args=(v, A_active, dg.V),
        whole_grid=whole_grid,
        active_cells=active_cells,
    )


def main():
    import jaxmpm

    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--n-grid", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "ddmp_active_cells.csv"))
    add_overwrite(ap)
    a = ap.parse_args()
    check_outputs(a.out, overwrite=a.overwrite)
    progs = []
    for groups in (((0, 1, 2),), ((0,), (1,), (2,))):
        c = case(a.n_grid, groups)
        ref = c["whole_grid"](*c["grid_args"])
        diff = float(jnp.max(jnp.abs(c["active_cells"](*c["list_args"]) - ref)) / jnp.max(jnp.abs(ref)))
        for form, args in (("whole grid", c["grid_args"]), ("active cells", c["list_args"])):
            f = c["whole_grid"] if form == "whole grid" else c["active_cells"]
            for mode in ("forward", "gradient"):
                fn = jaxmpm.jit(
                    f
                    if mode == "forward"
                    else jax.grad(lambda v, A, V, f=f: jnp.sum(jnp.sin(f(v, A, V))), argnums=(0, 1))
                )
                jax.block_until_ready(fn(*args))
                progs.append(
                    dict(
                        fields=c["fields"],
                        cells_per_field=c["active_fraction"],
                        form=form,
                        mode=mode,
                        rel_diff=diff,
                        fn=fn,
                        args=args,
                        best=float("inf"),
                    )
                )
    for _ in range(a.repeats):
        for p in progs:
            jax.block_until_ready(p["fn"](*p["args"]))
            t0 = time.perf_counter()
            jax.block_until_ready(p["fn"](*p["args"]))
            p["best"] = min(p["best"], time.perf_counter() - t0)
    print(
        f"DDMP nodal velocity gradient, {a.n_grid}^2 grid, float32, {describe()}, {os.cpu_count()} CPUs, "
        f"jax {jax.__version__} (fastest of {a.repeats})"
    )
    print(f"{'fields':>6} {'cells/field':>11} {'form':>12} {'mode':>8} {'ms':>8} {'rel. diff':>9}")
    rows = []
    for p in progs:
        print(
            f"{p['fields']:>6} {p['cells_per_field']:>11.3f} {p['form']:>12} {p['mode']:>8} {1e3 * p['best']:>8.3f} "
            f"{p['rel_diff']:>9.1e}"
        )
        rows.append(
            dict(
                fields=p["fields"],
                active_cell_fraction_per_field=p["cells_per_field"],
                form=p["form"],
                mode=p["mode"],
                ms=1e3 * p["best"],
                max_rel_diff_to_whole_grid=p["rel_diff"],
                device=describe(),
                cpus=os.cpu_count(),
                jax=jax.__version__,
                python=platform.python_version(),
            )
        )
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
