"""The experiment's table: axial velocities (km/s) of debris-cloud features (Piekutowski 1993),
with the seed's DDMP results for four values of C_h.

The package ships its own copy (calibration/data/piekutowski_debris_cloud.csv); a test checks it
equals the project's shared data. Columns: `point` (feature id: 1 leading edge of the cloud,
2 front of the projectile on the axis, 4 rear of the projectile on the axis), `experiment_km_s`,
and `ch_<value>` (the seed's computed velocity for C_h = value), all in km/s, downstream positive.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFAULT_CSV = Path(__file__).with_name("data") / "piekutowski_debris_cloud.csv"
POINTS = (1, 2, 4)  # the features jaxmpm.features measures, in this order
MAX_SPEED_KM_S = 20.0  # a sanity bound: the impact is at 6.71 km/s


@dataclass(frozen=True)
class Measurements:
    points: tuple[int, ...]  # (3,) feature ids, in POINTS order
    experiment: np.ndarray  # (3,) km/s
    seed: dict[float, np.ndarray]  # {C_h: (3,) km/s} the seed's computed velocities
    source: str

    def __post_init__(self) -> None:
        if tuple(self.points) != POINTS:
            raise ValueError(f"points {self.points} != {POINTS}")


def _number(text: str | None, row: int, column: str, path: Path) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(
            f"{path}: row {row}, column {column!r}: {text!r} is not a number (allowed a velocity in km/s)"
        ) from None
    if not np.isfinite(value) or value <= 0 or value > MAX_SPEED_KM_S:
        raise ValueError(
            f"{path}: row {row}, column {column!r}: {value!r} km/s is invalid: allowed "
            f"(0, {MAX_SPEED_KM_S}] km/s (downstream speeds are positive)"
        )
    return value


def load(path: str | os.PathLike | None = None) -> Measurements:
    """Read and check the table (default: the packaged copy). Raises ValueError naming the row
    (1-based, header excluded) and column of any missing column, non-numeric or out-of-range
    value, unknown or repeated point id, or missing point; FileNotFoundError naming a missing file."""
    path = DEFAULT_CSV if path is None else Path(path)
    if not path.exists():
        raise FileNotFoundError(
            f"{path}: no such file (allowed the path of a CSV table with columns point, experiment_km_s, ch_<C_h>)"
        )
    if not path.is_file():
        raise ValueError(
            f"{path} is not a file (allowed the path of a CSV table with columns point, experiment_km_s, ch_<C_h>)"
        )
    with open(path, newline="") as f:
        lines = [line for line in f if line.strip() and not line.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    header = reader.fieldnames or []
    for col in ("point", "experiment_km_s"):
        if col not in header:
            raise ValueError(
                f"{path}: column {col!r} is missing: the header has {header} "
                "(allowed: point, experiment_km_s, then ch_<C_h> columns in km/s)"
            )
    ch_cols = [c for c in header if c.startswith("ch_")]
    unknown = [c for c in header if c not in ("point", "experiment_km_s") and c not in ch_cols]
    if unknown:
        raise ValueError(f"{path}: column {unknown[0]!r} is unknown: allowed point, experiment_km_s, ch_<C_h>")
    ch_values = {}
    for c in ch_cols:
        try:
            ch_values[c] = float(c[3:])
        except ValueError:
            raise ValueError(f"{path}: column {c!r}: {c[3:]!r} is not a value of C_h (allowed ch_<number>)") from None
    rows = {}
    for i, row in enumerate(reader, start=1):
        text = (row.get("point") or "").strip()
        try:
            point = int(text)
        except ValueError:
            raise ValueError(f"{path}: row {i}, column 'point': {text!r} is not a point id: allowed {POINTS}") from None
        if point not in POINTS:
            raise ValueError(f"{path}: row {i}, column 'point': point {point} is unknown: allowed {POINTS}")
        if point in rows:
            raise ValueError(f"{path}: row {i}, column 'point': point {point} is repeated")
        if None in row or any(row.get(c) is None for c in header):
            raise ValueError(
                f"{path}: row {i}: has {len([v for v in row.values() if v is not None])} values, "
                f"the header {len(header)}: allowed one value per column"
            )
        rows[point] = {c: _number(row[c], i, c, path) for c in ["experiment_km_s"] + ch_cols}
    missing = [p for p in POINTS if p not in rows]
    if missing:
        raise ValueError(f"{path}: point {missing[0]} is missing: allowed rows for points {POINTS}")
    return Measurements(
        points=POINTS,
        experiment=np.array([rows[p]["experiment_km_s"] for p in POINTS]),
        seed={ch_values[c]: np.array([rows[p][c] for p in POINTS]) for c in ch_cols},
        source=str(path),
    )
