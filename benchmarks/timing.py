"""The benchmarks' timing of whole steps: each configuration compiled as one `jaxmpm.jit` loop of
`steps` steps, run once from the initial state (compiling it), then `repeats` times from the state
that run reached, the configurations interleaved so that a change of the machine's load falls on
all of them alike. And the CSV the benchmarks write, under a comment line that says what ran."""

from __future__ import annotations

import csv
import datetime
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import jax

import jaxmpm


def step_loop(scene, params, steps: int):
    """(run, state): a jitted loop of `steps` steps of `scene` from a state, and the state that
    one run from the initial state reaches (it compiles the loop)."""
    step = jaxmpm.make_step(scene)
    run = jaxmpm.jit(lambda s: jax.lax.fori_loop(0, steps, lambda i, s: step(params, s), s))
    return run, jax.block_until_ready(run(jaxmpm.init_state(scene, params)))


def interleaved_ms_per_step(loops: dict[str, Callable[[], tuple]], steps: int, repeats: int) -> dict[str, list]:
    """{name: [ms per step of each timed run]}: loops maps each configuration's name to a function
    that builds its `step_loop` (called once, in order, each under whatever it patches), then the
    loops run `repeats` rounds, one run of each configuration per round."""
    built = {name: make() for name, make in loops.items()}
    times = {name: [] for name in loops}
    for _ in range(repeats):
        for name, (run, state) in built.items():
            t0 = time.perf_counter()
            jax.block_until_ready(run(state))
            times[name].append((time.perf_counter() - t0) / steps * 1e3)
    return times


def write_csv(out: Path, name: str, rows: list[dict], note: str = "") -> None:
    """rows as a CSV under '# jaxmpm <name>, <date>, jax <version>, <platform>[, note]'."""
    with open(out, "w", newline="") as f:
        f.write(
            f"# jaxmpm {name}, {datetime.date.today()}, jax {jax.__version__}, {jax.devices()[0].platform}"
            + (f", {note}" if note else "")
            + "\n"
        )
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out}")


def cost_rows(times: dict[str, list], baseline: str, labels: dict, ratio_name: str) -> list[dict]:
    """One row per configuration of `times` ({name: [ms per step of each run]}, as
    `interleaved_ms_per_step` gives): `labels` (the columns that say what was measured), the name as
    `config`, the median and the fastest ms per step, their ratios to `baseline`'s (columns
    ratio_name and 'fastest_' + ratio_name) and the runs; each row printed."""
    base, fastest = statistics.median(times[baseline]), min(times[baseline])
    rows = []
    for name, t in times.items():
        row = {
            **labels,
            "config": name,
            "ms_per_step": statistics.median(t),
            ratio_name: statistics.median(t) / base,
            "fastest_ms_per_step": min(t),
            f"fastest_{ratio_name}": min(t) / fastest,
            "runs_ms": " ".join(f"{x:.3f}" for x in t),
        }
        rows.append(row)
        print(
            f"{' '.join(str(v) for v in labels.values()):18s} {name:40s} {row['ms_per_step']:.3f} ms/step, "
            f"x{row[ratio_name]:.3f}; fastest {min(t):.3f}, x{min(t) / fastest:.3f} (runs {row['runs_ms']})",
            flush=True,
        )
    return rows
