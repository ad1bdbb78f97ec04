"""Kernels per step: what XLA compiles one step into, per scheme and transfer form, on this backend.

What it counts: the optimized HLO of one compiled step (`jaxmpm.jit(step).lower(...).compile()
.as_text()`, the peers' mpm88 scene, float32) is split into its computations; those that a fusion
calls (or a scatter or reduction applies) are inside a kernel, the others (the entry, loop bodies
and conditions, conditional branches) hold the instructions that run as kernels or library calls.
Per step it reports:
  kernels    the instructions of those computations that compute (fusions, scatters, gathers, dots,
             custom calls, copies, ...; not parameters, constants, tuples, bitcasts), each once;
  launches   the same with each loop body's kernels counted as many times as the loop runs (XLA's
             known trip count; 1 where it is unknown): the kernels a step launches on a GPU;
  fusions    the fusion instructions among the kernels;
  loops      while loops (the CPU form's loops over stencil offsets and cell corners, the scan of
             the step's sub-steps if any);
  scatters   kernels that scatter (a scatter instruction, or a fusion whose computation holds one);
  gathers    the same for gathers (a dynamic slice of a loop counts as neither).
Schemes: APIC (quadratic B-spline, the peers' transfer), linear musl and DDMP musl (the default
scheme), in 2D and 3D, each traced in the CPU form and the GPU form of the transfers
(jaxmpm/forms.py; either runs on any backend). Counts depend little on the grid's size (XLA may
pick other loop emitters for other shapes), so small grids are the default.

Run:  python benchmarks/kernel_count.py                    # 2D 32^2, 3D 16^3
      python benchmarks/kernel_count.py --n-grid-2d 128 --n-grid-3d 64
Writes benchmarks/results/kernel_count_<backend>.csv and .md (or --out NAME.csv, and NAME.md) and
prints the table.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import re
import sys
import time
from pathlib import Path

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py

HERE = Path(__file__).resolve().parent
SCHEMES = {"apic": ("bspline2", "apic"), "linear-musl": ("linear", "musl"), "ddmp-musl": ("ddmp", "musl")}
# instructions that compute nothing on the device (views, tuples, constants, control)
FREE = {
    "parameter",
    "constant",
    "get-tuple-element",
    "tuple",
    "bitcast",
    "after-all",
    "partition-id",
    "replica-id",
    "opt-barrier",
    "add-dependency",
    "domain",
}
FIELDS = [
    "scheme",
    "dim",
    "n_grid",
    "form",
    "particles",
    "kernels",
    "launches",
    "fusions",
    "loops",
    "scatters",
    "gathers",
    "compile_s",
    "backend",
    "device",
    "jax_version",
    "date",
]

_COMP = re.compile(r"^(ENTRY\s+)?%?([\w.\-]+)\s.*\{\s*$")
_INSTR = re.compile(r"^\s*(ROOT\s+)?%?[\w.\-]+\s*=\s*(.*?)\s([a-z][\w\-]*)\((.*)$")


def computations(hlo: str) -> dict:
    """{name: [(opcode, rest of line)]} of an HLO module's text; the entry is named 'ENTRY'."""
    comps, name = {}, None
    for line in hlo.splitlines():
        if name is None:
            m = _COMP.match(line)
            if m and not line.startswith("HloModule"):
                name = "ENTRY" if m.group(1) else m.group(2)
                comps[name] = []
            continue
        if line.strip() == "}":
            name = None
            continue
        m = _INSTR.match(line)
        if m:
            comps[name].append((m.group(3), m.group(4)))
    return comps


def _called(rest: str, key: str) -> list[str]:
    m = re.search(key + r"=\{?%?([\w.\-]+(?:,\s*%?[\w.\-]+)*)\}?", rest)
    return [c.strip().lstrip("%") for c in m.group(1).split(",")] if m else []


def _trip_count(rest: str) -> int:
    m = re.search(r'"known_trip_count":\{"n":"(\d+)"', rest)
    return int(m.group(1)) if m else 1


def count_kernels(hlo: str) -> dict:
    """kernels, launches, fusions, loops, scatters, gathers of an optimized HLO module's text (see
    the module docstring)."""
    comps = computations(hlo)

    def holds(comp, ops, seen=()):
        """Whether a fused computation (or one it calls) holds one of ops."""
        if comp in seen or comp not in comps:
            return False
        return any(
            op in ops or any(holds(c, ops, seen + (comp,)) for c in _called(rest, "calls")) for op, rest in comps[comp]
        )

    totals = dict(kernels=0, launches=0, fusions=0, loops=0, scatters=0, gathers=0)

    def visit(comp, times):
        for op, rest in comps.get(comp, []):
            if op == "while":
                totals["loops"] += 1
                n = _trip_count(rest)
                for c in _called(rest, "body"):
                    visit(c, times * n)
                for c in _called(rest, "condition"):
                    visit(c, times * (n + 1))
                continue
            if op in ("conditional", "call"):
                branches = (
                    _called(rest, "branch_computations")
                    + _called(rest, "true_computation")
                    + _called(rest, "false_computation")
                    + (_called(rest, "to_apply") if op == "call" else [])
                )
                for c in branches:
                    visit(c, times)
                if op == "conditional":
                    totals["kernels"] += 1  # the predicate's read
                    totals["launches"] += times
                continue
            if op in FREE:
                continue
            totals["kernels"] += 1
            totals["launches"] += times
            fused = _called(rest, "calls") if op == "fusion" else []
            totals["fusions"] += op == "fusion"
            totals["scatters"] += op == "scatter" or any(holds(c, ("scatter",)) for c in fused)
            totals["gathers"] += op == "gather" or any(holds(c, ("gather",)) for c in fused)

    visit("ENTRY", 1)
    return totals


def count_step(scheme: str, dim: int, n_grid: int, form: str) -> dict:
    """The counts of one compiled step of mpm88 with `scheme`, traced in `form`."""
    import jax
    import jax.numpy as jnp

    import jaxmpm
    from jaxmpm.numerics.forms import transfer_forms

    shape, transfer = SCHEMES[scheme]
    scene = jaxmpm.load_scene("mpm88", n_grid=n_grid, dim=dim, ppc_scale=1e-9)  # 1 particle per cell
    scene = dataclasses.replace(scene, shape=shape, transfer=transfer)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    dt = jnp.asarray(1e-4, jnp.float32)
    t0 = time.perf_counter()
    with transfer_forms(form):
        step = jaxmpm.make_step(scene)
        hlo = jaxmpm.jit(lambda p, s, dt: step(p, s, jnp.inf, dt)).lower(params, state, dt).compile().as_text()
    return dict(
        scheme=scheme,
        dim=dim,
        n_grid=n_grid,
        form=form,
        particles=int(state.n_particles),
        compile_s=round(time.perf_counter() - t0, 2),
        backend=jax.default_backend(),
        device=describe(),
        jax_version=jax.__version__,
    ) | count_kernels(hlo)


def markdown(rows) -> str:
    """The table as markdown: one line per scheme and dimension, the two forms side by side."""
    head = (
        "| scheme | dim | grid | kernels cpu / gpu form | launches cpu / gpu | fusions cpu / gpu | loops cpu / gpu "
        "| scatters cpu / gpu | gathers cpu / gpu |\n|---|---|---|---|---|---|---|---|---|\n"
    )
    by = {(r["scheme"], r["dim"], r["form"]): r for r in rows}
    lines = []
    for scheme, dim in dict.fromkeys((r["scheme"], r["dim"]) for r in rows):
        c, g = by.get((scheme, dim, "cpu"), {}), by.get((scheme, dim, "gpu"), {})
        pair = lambda k: f"{c.get(k, '')} / {g.get(k, '')}"
        n = (c or g)["n_grid"]
        lines.append(
            f"| {scheme} | {dim} | {n}^{dim} | {pair('kernels')} | {pair('launches')} | {pair('fusions')} | "
            f"{pair('loops')} | {pair('scatters')} | {pair('gathers')} |"
        )
    r0 = rows[0]
    return (
        f"Kernels per step of mpm88 (one compiled step, float32), {r0['backend']} backend, {r0['device']}, "
        f"jax {r0['jax_version']}, {r0['date']}\n\n" + head + "\n".join(lines) + "\n"
    )


def write(rows, out: Path):
    """The table as CSV at out and as markdown beside it (.md)."""
    with open(out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    out.with_suffix(".md").write_text(markdown(rows))


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--n-grid-2d", type=int, default=32, help="2D grid cells per axis (default 32)")
    ap.add_argument("--n-grid-3d", type=int, default=16, help="3D grid cells per axis (default 16)")
    ap.add_argument("--schemes", default=",".join(SCHEMES), help="comma-separated, of " + ", ".join(SCHEMES))
    ap.add_argument("--dims", default="2,3", help="comma-separated dimensions (default 2,3)")
    ap.add_argument(
        "--out", default=None, help="CSV to write, the markdown beside it (default results/kernel_count_<backend>.csv)"
    )
    add_overwrite(ap)
    a = ap.parse_args(argv)
    schemes = [s.strip() for s in a.schemes.split(",") if s.strip()]
    bad = sorted(set(schemes) - set(SCHEMES))
    if bad:
        ap.error(f"--schemes {','.join(bad)} is invalid: allowed {', '.join(SCHEMES)}")
    try:
        dims = [int(d) for d in a.dims.split(",")]
    except ValueError:
        dims = [0]
    if not dims or any(d not in (2, 3) for d in dims):
        ap.error(f"--dims {a.dims} is invalid: allowed 2, 3 or 2,3")
    for name, n in (("--n-grid-2d", a.n_grid_2d), ("--n-grid-3d", a.n_grid_3d)):
        if n < 8:
            ap.error(f"{name} {n} is invalid: allowed an integer >= 8")
    import jax

    out = Path(a.out) if a.out else HERE / "results" / f"kernel_count_{jax.default_backend()}.csv"
    check_outputs(out, out.with_suffix(".md"), overwrite=a.overwrite)
    date = datetime.datetime.now().isoformat(timespec="seconds")
    rows = []
    for scheme in schemes:
        for dim in dims:
            for form in ("cpu", "gpu"):
                r = count_step(scheme, dim, a.n_grid_2d if dim == 2 else a.n_grid_3d, form) | dict(date=date)
                print(
                    f"  {scheme:12s} {dim}D {form} form: {r['kernels']} kernels, {r['launches']} launches, "
                    f"{r['loops']} loops, {r['scatters']} scatters ({r['compile_s']:.1f} s to compile)",
                    file=sys.stderr,
                    flush=True,
                )
                rows.append(r)
                write(rows, out)  # after every row: a run stopped at a time limit keeps its counts
    print(markdown(rows))
    print(f"wrote {out} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
