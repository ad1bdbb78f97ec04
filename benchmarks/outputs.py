"""Where the benchmarks write. Their tables and figures under benchmarks/results are the project's
(kept in git, rewritten by every run); a file anywhere else that already exists is a user's, so a
benchmark refuses it before it measures anything, unless --overwrite is given."""

from __future__ import annotations

import csv
import os
import sys
from pathlib import Path

RESULTS = (Path(__file__).parent / "results").resolve()


def add_overwrite(parser) -> None:
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace existing files outside benchmarks/results (those are rewritten freely)",
    )


def check_outputs(*paths, overwrite: bool = False) -> None:
    """Exit with status 2 naming the first of `paths` that is a folder, or that exists outside
    benchmarks/results without `overwrite`; else create the folders the paths need."""
    for p in map(Path, paths):
        if p.is_dir():
            sys.exit(_error(f"{p} is a folder: allowed a file name"))
        if p.exists() and not overwrite and p.resolve().parent != RESULTS:
            sys.exit(_error(f"{p} exists: refusing to overwrite it (pass --overwrite, or another --out)"))
    for p in map(Path, paths):
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            sys.exit(_error(f"cannot create the folder {p.parent}: {e.strerror or e}"))


def check_table(path) -> Path:
    """A CSV table to read (--replot): exit with status 2 unless it is an existing .csv file."""
    p = Path(path)
    if p.suffix != ".csv" or not p.is_file():
        sys.exit(_error(f"{os.fspath(path)} is invalid: allowed an existing .csv table written by this benchmark"))
    return p


def print_and_write_table(rows: list[dict], path, width: int = 14) -> None:
    """Print rows (dicts with the same keys) as a table of columns `width` wide (floats to 4
    significant digits) and write them to the CSV file `path`."""
    keys = list(rows[0])
    print(" ".join(f"{k:>{width}}" for k in keys))
    for r in rows:
        print(" ".join(f"{v:>{width}.4g}" if isinstance(v, float) else f"{v!s:>{width}}" for v in r.values()))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)


def _error(message: str) -> int:
    print(f"error: {message}", file=sys.stderr)
    return 2
