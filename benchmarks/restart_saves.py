"""Cost of a restart-file save against the number of outputs saved before it.

What it measures: the host driver saves the restart file at each output (and every few chunks).
A run's first save writes the whole file (`restart.save`, atomically); its later ones append the
outputs finished since and overwrite the state in place (`append=True`). For a built-in scene's
initial state, this saves outputs 1, 2, ..., N one by one and reports the median time and the
bytes written (Linux: /proc/self/io wchar) of the saves around each reported count, for the
append and, up to --full-max outputs, for a whole-file rewrite at each save (the layout of a
restart file is the same both ways).

Run:  python benchmarks/restart_saves.py                          # elastic_impact at resolution 0.25
      python benchmarks/restart_saves.py --outputs 2000 --scene taylor_bar
Writes benchmarks/results/restart_saves.csv (or --out) with device, CPU count and date.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from outputs import RESULTS, add_overwrite, check_outputs  # noqa: E402


def _written() -> int | None:
    try:
        with open("/proc/self/io") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("wchar:"))
    except OSError:
        return None


def measure(scene, params, state, n, append, report, folder):
    """[(outputs saved before, median ms, median bytes)] over the saves just before each count in report."""
    from jaxmpm import restart

    path = Path(folder) / f"{'append' if append else 'full'}.restart.h5"
    kw = dict(t0=0.0, t_end=1.0, n_out=n, chunk=1, dt=None)
    history = [state]
    restart.save(path, scene, params, state, history, next_out=0, **kw)
    rows, times, sizes = [], [], []
    for k in range(1, n + 1):
        history.append(state)
        w0, t0 = _written(), time.perf_counter()
        restart.save(path, scene, params, state, history, next_out=k, append=append, **kw)
        times.append(time.perf_counter() - t0)
        sizes.append(None if w0 is None else _written() - w0)
        if k in report:
            last = slice(max(0, len(times) - 5), None)
            rows.append(
                (
                    k,
                    1e3 * statistics.median(times[last]),
                    None if sizes[-1] is None else int(statistics.median(sizes[last])),
                )
            )
    path.unlink()
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--scene", default="elastic_impact")
    ap.add_argument("--resolution", type=float, default=0.25)
    ap.add_argument("--outputs", type=int, default=1000, help="outputs saved one by one (default 1000)")
    ap.add_argument("--full-max", type=int, default=300, help="outputs up to which the whole-file rewrite is timed")
    ap.add_argument("--out", default=str(RESULTS / "restart_saves.csv"))
    add_overwrite(ap)
    args = ap.parse_args(argv)
    check_outputs(args.out, overwrite=args.overwrite)

    import jax
    import numpy as np

    import jaxmpm

    scene = jaxmpm.load_scene(args.scene, resolution=args.resolution)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    state_bytes = sum(np.asarray(a).nbytes for a in jax.tree.leaves(state))
    report = sorted({k for k in (5, 10, 30, 100, 300, 1000, 3000, 10000) if k <= args.outputs} | {args.outputs})
    table = []
    with tempfile.TemporaryDirectory() as folder:
        for append, n in ((True, args.outputs), (False, min(args.full_max, args.outputs))):
            for k, ms, b in measure(scene, params, state, n, append, [r for r in report if r <= n], folder):
                table.append(("append" if append else "rewrite", k, ms, b))
    header = (
        f"{args.scene} (resolution {args.resolution}): {state.x.shape[0]} particles, a state {state_bytes / 1e3:.1f} kB; "
        f"{jax.devices()[0]}, {os.cpu_count()} CPUs, {datetime.date.today()}"
    )
    print(header)
    print(f"{'save':<8}{'outputs before':>15}{'ms per save':>13}{'bytes written':>15}")
    for mode, k, ms, b in table:
        print(f"{mode:<8}{k:>15}{ms:>13.2f}{'' if b is None else b:>15}")
    with open(args.out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["# " + header])
        w.writerow(["save", "outputs_before", "ms_per_save", "bytes_written"])
        for mode, k, ms, b in table:
            w.writerow([mode, k, f"{ms:.3f}", "" if b is None else b])
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
