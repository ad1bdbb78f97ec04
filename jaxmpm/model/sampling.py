"""Sampling of a scene's geometry into particles: the lattice each phase lays over its bounding
box, the positions it keeps, and the checks a Scene runs on them when it is built."""

from __future__ import annotations

import functools

import numpy as np

from jaxmpm.model.geometry import Grid
from jaxmpm.model.parts import Phase
from jaxmpm.model.scene_fields import SceneFields


def lattice_cells(grid: Grid, phase: Phase) -> tuple[np.ndarray, np.ndarray]:
    """(first, past-last) cell index per axis (d,) int64 of the grid cells the phase's bounding box
    touches: `sample_phase` lays its lattice over them."""
    lo = np.asarray(grid.origin, float)
    c_lo = np.maximum(np.floor((np.asarray(phase.geometry.lo) - lo) / grid.h).astype(np.int64), 0)
    c_hi = np.minimum(np.ceil((np.asarray(phase.geometry.hi) - lo) / grid.h).astype(np.int64), np.asarray(grid.cells))
    return c_lo, c_hi


@functools.lru_cache(maxsize=64)
def sample_phase(grid: Grid, phase: Phase) -> np.ndarray:
    """Particle positions (n, d) of a phase: ppc^d points per cell on a regular lattice,
    kept where inside the geometry. Deterministic."""
    h, ppc, d = grid.h, phase.ppc, grid.dim
    lo = np.asarray(grid.origin)
    c_lo, c_hi = lattice_cells(grid, phase)
    axes = [lo[k] + (np.arange(c_lo[k] * ppc, c_hi[k] * ppc) + 0.5) * h / ppc for k in range(d)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d)
    return pts[phase.geometry.contains(pts)]


def usable_region(scene: SceneFields) -> tuple[float, np.ndarray, np.ndarray]:
    """(margin, lo, hi): the part of the grid where a particle's stencil stays on the grid, lo and hi
    (d,) m, `margin` cells in from each face (half a cell for the quadratic B-spline, else none)."""
    margin = 0.5 if scene.shape == "bspline2" else 0.0
    lo = np.asarray(scene.grid.origin) + margin * scene.grid.h
    hi = np.asarray(scene.grid.hi) - margin * scene.grid.h
    return margin, lo, hi


def check_sampling(scene: SceneFields) -> None:
    """Raise ValueError if a phase has no particle, a particle lies where its stencil leaves the
    grid, or bodies of one velocity field overlap with volume fractions that sum to more than 1
    (two coincident bodies of fraction 1 would double the mass of that continuum there; a mixture's
    phases in one field share a region with fractions that sum to at most 1). Bodies of different
    fields may interpenetrate: each field is its own continuum, coupled by the volume fractions."""
    margin, lo, hi = usable_region(scene)
    for p in scene.phases:
        x = sample_phase(scene.grid, p)
        total = np.full(len(x), float(p.fraction))
        for q in scene.phases:
            if q is not p and q.field == p.field:
                inside = q.geometry.contains(x)
                total = total + q.fraction * inside
                if (total > 1 + 1e-9).any():
                    i = int(np.argmax(total > 1 + 1e-9))
                    raise ValueError(
                        f"phase.{p.name}.geometry overlaps phase.{q.name}.geometry in velocity field {p.field} "
                        f"(e.g. at {x[i].tolist()} m), where their volume fractions sum to {total[i]:g}: allowed "
                        "bodies of one field that do not overlap, or phases of a mixture whose fractions sum to <= 1 "
                        "where they share space (bodies of different fields may interpenetrate)"
                    )
        if len(x) == 0:
            raise ValueError(
                f"phase.{p.name}.geometry = {p.geometry.to_dict()} holds no particle: make it larger than a cell or raise ppc"
            )
        i = first_outside(x, lo, hi)
        if i is not None:
            raise ValueError(
                f"phase.{p.name}.geometry: particle {i} at {x[i].tolist()} lies outside the grid's usable "
                f"region [{lo.tolist()}, {hi.tolist()}] m (shape {scene.shape!r} needs {margin} cell of margin)"
            )


def first_outside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> int | None:
    """The index of the first of the points x (N, d) outside the box [lo, hi] (d,), or None."""
    out = np.any((x < lo) | (x > hi), axis=1)
    return int(np.argmax(out)) if out.any() else None
