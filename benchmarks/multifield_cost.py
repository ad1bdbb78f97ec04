"""Cost of a multi-velocity step: the same particles grouped into 1, 2 and 3 velocity fields.

Scene: a 2D impact of three elastic blocks (a striker, a plate, a backing block) on a 128^2 grid,
2 x 2 particles per cell, DDMP, the default update; with 2 and 3 fields the exchange (E3, E14) and
the interface forces (E6, E13) are on, with the continuity form (E7, the default) and without it
(continuity = 'off', the E15 fit); and 1 and 3 fields with the DDMP operators on each field's
block of cells (Scene.window, from `ddmp.fitting_window` with a margin of 4 cells). Prints microseconds per step and per particle-step and the
ratio to one field (every case compiled first, then timed in interleaved rounds, the fastest
round counting, so the ratios come from one stretch of the machine's load); writes
benchmarks/results/multifield_cost.csv and a bar chart of the ratios
(multifield_cost.png, with the target of 2x one field marked).

    python benchmarks/multifield_cost.py [--steps 100] [--repeats 7] [--x64]
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import platform
import time

import jax

from devices import describe  # benchmarks/devices.py
from outputs import add_overwrite, check_outputs  # benchmarks/outputs.py


def scene_for(n_fields, n_grid, continuity="auto", window=False):
    """The scene; window=True: with each field's DDMP operators on a block of cells that holds the
    largest field's initial extent plus 4 cells on each side."""
    import jaxmpm
    from jaxmpm.model.scene import Box, Grid, Phase, Scene

    mat = jaxmpm.Material.make("al", "linear_elastic", rho0=2700.0, E=70e9, nu=0.33)
    groups = {1: (0, 0, 0), 2: (0, 1, 1), 3: (0, 1, 2)}[n_fields]
    phases = (
        Phase("striker", "al", Box((0.40, 0.62), (0.60, 0.80)), velocity=(0.0, -500.0), field=groups[0]),
        Phase("plate", "al", Box((0.20, 0.50), (0.80, 0.60)), field=groups[1]),
        Phase("backing", "al", Box((0.20, 0.20), (0.80, 0.48)), field=groups[2]),
    )
    scene = Scene(
        grid=Grid(cells=(n_grid, n_grid), h=1.0 / n_grid),
        materials=(mat,),
        phases=phases,
        drag=1e3 if n_fields > 1 else None,
        continuity=continuity,
        name=f"impact_{n_fields}_fields",
    )
    if window:
        x = jaxmpm.init_state(scene, jaxmpm.default_params(scene)).x
        scene = dataclasses.replace(scene, window=jaxmpm.numerics.ddmp.fitting_window(scene, x, margin=4))
    return scene


def compile_case(n_fields, n_grid, steps, continuity="auto", window=False):
    """The compiled `steps`-step run of one case, its inputs and facts for the table."""
    import jaxmpm

    scene = scene_for(n_fields, n_grid, continuity, window)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    step = jaxmpm.make_step(scene)
    run = jaxmpm.jit(lambda p, s: jax.lax.scan(lambda c, _: (step(p, c), None), s, None, length=steps)[0])
    t0 = time.perf_counter()
    state = jax.block_until_ready(run(params, state))
    compile_s = time.perf_counter() - t0
    finite = bool(jax.numpy.all(jax.numpy.isfinite(state.x)))
    return dict(
        run=run,
        params=params,
        state=state,
        row=dict(
            fields=n_fields,
            continuity=scene.continuity_form,
            window="x".join(map(str, scene.window)) if scene.window else "grid",
            particles=state.x.shape[0],
            steps=steps,
            compile_s=compile_s,
            finite=finite,
        ),
    )


def time_interleaved(cases, repeats):
    """Fastest wall seconds of each case's run over `repeats` rounds; every round runs each case
    once untimed, then timed (the first run of a program after another, larger one can be slower)."""
    best = [float("inf")] * len(cases)
    for _ in range(repeats):
        for i, c in enumerate(cases):
            jax.block_until_ready(c["run"](c["params"], c["state"]))
            t0 = time.perf_counter()
            jax.block_until_ready(c["run"](c["params"], c["state"]))
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def measure_all(configs, n_grid, steps, repeats):
    """Rows of the table for configs [(n_fields, continuity, window)], timed interleaved in one run."""
    cases = [compile_case(k, n_grid, steps, c, w) for k, c, w in configs]
    rows = []
    for c, sec in zip(cases, time_interleaved(cases, repeats)):
        r = c["row"]
        n = r["particles"]
        rows.append(
            dict(
                fields=r["fields"],
                continuity=r["continuity"],
                window=r["window"],
                particles=n,
                steps=steps,
                seconds=sec,
                us_per_step=1e6 * sec / steps,
                ns_per_particle_step=1e9 * sec / steps / n,
                compile_s=r["compile_s"],
                finite=r["finite"],
            )
        )
    return rows


def plot(rows, path):
    """Bars of the cost per particle-step relative to one field, by field count and continuity form."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.8))
    labels = [
        f"{r['fields']} field{'s' if r['fields'] > 1 else ''}"
        + (f"\n{r['continuity']}" if r["fields"] > 1 else "")
        + ("" if r["window"] == "grid" else f"\nblocks {r['window']}")
        for r in rows
    ]
    ratios = [r["ratio_to_1_field"] for r in rows]
    ax.bar(
        range(len(rows)),
        ratios,
        color=["0.6" if r["fields"] == 1 else ("C0" if r["window"] == "grid" else "C2") for r in rows],
    )
    for i, v in enumerate(ratios):
        ax.text(i, v, f"{v:.2f}", ha="center", va="bottom", fontsize="small")
    ax.axhline(2.0, color="r", ls="--", lw=1, label="target: 3 fields <= 2x one field")
    ax.set_xticks(range(len(rows)), labels, fontsize="small")
    ax.set_ylabel("cost per particle-step\n/ one field, same DDMP grid")
    ax.set_title(
        f"multi-field DDMP step ({rows[0]['particles']} particles; {describe()}, {os.cpu_count()} CPUs)",
        fontsize="medium",
    )
    ax.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--n-grid", type=int, default=128)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=7, help="interleaved rounds; the fastest counts")
    ap.add_argument("--x64", action="store_true")
    ap.add_argument("--short", action="store_true", help="one field and three (continuity form) on the whole grid only")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "multifield_cost.csv"))
    add_overwrite(ap)
    a = ap.parse_args()
    check_outputs(a.out, os.path.splitext(a.out)[0] + ".png", overwrite=a.overwrite)
    if a.x64:
        jax.config.update("jax_enable_x64", True)
    configs = [(1, "auto", False)] + [(k, c, False) for c in ("transport", "off") for k in (2, 3)]
    configs += [(1, "auto", True), (3, "transport", True)]
    if a.short:
        configs = [(1, "auto", False), (3, "transport", False)]
    rows = measure_all(configs, a.n_grid, a.steps, a.repeats)
    base = {
        w: next(r for r in rows if r["fields"] == 1 and (r["window"] != "grid") == w)["ns_per_particle_step"]
        for w in (False, True)
        if any(r["fields"] == 1 and (r["window"] != "grid") == w for r in rows)
    }
    print(
        f"multi-field DDMP step, {a.n_grid}^2 grid, {'float64' if a.x64 else 'float32'}, {describe()}, "
        f"{os.cpu_count()} CPUs, jax {jax.__version__}"
    )
    print(
        "x 1 field: against one field computed the same way (whole grid, or blocks); x grid: against one field on the whole grid"
    )
    print(
        f"{'fields':>6} {'continuity':>10} {'DDMP on':>8} {'particles':>9} {'us/step':>9} {'ns/part-step':>12} "
        f"{'x 1 field':>9} {'x grid':>6} {'finite':>6}"
    )
    for r in rows:
        r["ratio_to_1_field"] = r["ns_per_particle_step"] / base[r["window"] != "grid"]
        r["ratio_to_1_field_grid"] = r["ns_per_particle_step"] / base[False]
        print(
            f"{r['fields']:>6} {r['continuity']:>10} {r['window']:>8} {r['particles']:>9} {r['us_per_step']:>9.0f} "
            f"{r['ns_per_particle_step']:>12.1f} {r['ratio_to_1_field']:>9.2f} {r['ratio_to_1_field_grid']:>6.2f} {str(r['finite']):>6}"
        )
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) + ["device", "cpus", "jax", "python"])
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    **r,
                    "device": describe(),
                    "cpus": os.cpu_count(),
                    "jax": jax.__version__,
                    "python": platform.python_version(),
                }
            )
    png = os.path.splitext(a.out)[0] + ".png"
    plot(rows, png)
    print(f"wrote {a.out} and {png}")


if __name__ == "__main__":
    main()
