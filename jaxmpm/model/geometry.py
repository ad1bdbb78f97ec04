"""Geometry of a scene: the bodies phases fill (Box, Sphere, Difference) and the fixed Cartesian
grid, each validated when built (ValueError naming the field and the allowed range). SI units."""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np


def fail(name: str, value: Any, allowed: str) -> None:
    """Raise the project's bad-input ValueError: the field `name`, its `value` and what is allowed."""
    raise ValueError(f"{name} = {value!r} is invalid: allowed {allowed}")


def is_number(v: Any) -> bool:
    """A real number (Python or NumPy scalar), not a bool and not a string of digits."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def is_integer(v: Any) -> bool:
    """An integer (Python or NumPy), not a bool."""
    return isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_))


def as_floats(name: str, value: Any, n: int | None = None) -> tuple[float, ...]:
    """A list of finite numbers (n of them, one per axis, where n is given) as floats. A string is
    not a list of numbers (it would be read digit by digit)."""
    if is_number(value):
        value = (value,)
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
        fail(name, value, "a list of numbers" if n != 1 else "a number")
    value = tuple(value)
    if not all(is_number(v) for v in value):
        fail(name, value, "a list of numbers")
    out = tuple(float(v) for v in value)
    if n is not None and len(out) != n:
        fail(name, value, f"a list of {n} numbers (one per axis)")
    if not all(math.isfinite(v) for v in out):
        fail(name, value, "finite numbers")
    return out


def as_float(name: str, value: Any) -> float:
    """One finite number as a float (a list, even of one number, or a string is refused)."""
    if not is_number(value):
        fail(name, value, "a number")
    if not math.isfinite(float(value)):
        fail(name, value, "a finite number")
    return float(value)


# ----------------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class Box:
    """Axis-aligned box [lo, hi] (m)."""

    lo: tuple[float, ...]
    hi: tuple[float, ...]

    def __post_init__(self):
        object.__setattr__(self, "lo", as_floats("geometry.lo", self.lo))
        object.__setattr__(self, "hi", as_floats("geometry.hi", self.hi, len(self.lo)))
        for d, (a, b) in enumerate(zip(self.lo, self.hi)):
            if not b > a:
                fail(f"geometry.hi[{d}]", b, f"> geometry.lo[{d}] = {a}")

    def contains(self, x: np.ndarray) -> np.ndarray:
        return np.all((x >= np.asarray(self.lo)) & (x < np.asarray(self.hi)), axis=-1)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "box", "lo": list(self.lo), "hi": list(self.hi)}


@dataclass(frozen=True)
class Sphere:
    """Ball of radius `radius` (m) around `center` (a disk in 2D, a segment in 1D)."""

    center: tuple[float, ...]
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "center", as_floats("geometry.center", self.center))
        r = as_float("geometry.radius", self.radius)
        if not r > 0:
            fail("geometry.radius", r, "> 0 m")
        object.__setattr__(self, "radius", r)

    @property
    def lo(self) -> tuple[float, ...]:
        return tuple(c - self.radius for c in self.center)

    @property
    def hi(self) -> tuple[float, ...]:
        return tuple(c + self.radius for c in self.center)

    def contains(self, x: np.ndarray) -> np.ndarray:
        return np.sum((x - np.asarray(self.center)) ** 2, axis=-1) < self.radius**2

    def to_dict(self) -> dict[str, Any]:
        return {"type": "sphere", "center": list(self.center), "radius": self.radius}


@dataclass(frozen=True)
class Difference:
    """The points of `base` (Box or Sphere) outside every geometry in `minus` (m): a fluid around a
    body, a plate with a hole. Particles are sampled on `base`'s cells."""

    base: Any
    minus: tuple = ()

    def __post_init__(self):
        if not isinstance(self.base, (Box, Sphere)):
            fail("geometry.base", self.base, "a Box or Sphere")
        minus = (self.minus,) if isinstance(self.minus, (Box, Sphere, Difference)) else tuple(self.minus)
        for part in minus:
            if not isinstance(part, (Box, Sphere, Difference)):
                fail("geometry.minus", part, "a list of Box, Sphere or Difference")
            if len(part.lo) != len(self.base.lo):
                fail("geometry.minus", part.to_dict(), f"{len(self.base.lo)} coordinates per point, as the base")
        object.__setattr__(self, "minus", minus)

    @property
    def lo(self) -> tuple[float, ...]:
        return self.base.lo

    @property
    def hi(self) -> tuple[float, ...]:
        return self.base.hi

    def contains(self, x: np.ndarray) -> np.ndarray:
        inside = self.base.contains(x)
        for part in self.minus:
            inside = inside & ~part.contains(x)
        return inside

    def to_dict(self) -> dict[str, Any]:
        return {"type": "difference", "base": self.base.to_dict(), "minus": [part.to_dict() for part in self.minus]}


GEOMETRIES = {"box": Box, "sphere": Sphere, "difference": Difference}


def geometry_from_dict(d: Mapping, where: str) -> Box | Sphere | Difference:
    """Box, Sphere or Difference from its scene-file table; ValueError naming `where` on bad input."""
    if not isinstance(d, Mapping):
        fail(where, d, "a table with key 'type' (box | sphere | difference)")
    d = dict(d)
    kind = d.pop("type", None)
    if not isinstance(kind, str) or kind not in GEOMETRIES:
        fail(f"{where}.type", kind, " | ".join(GEOMETRIES))
    cls = GEOMETRIES[kind]
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = set(d) - set(names)
    if unknown:
        fail(f"{where}.{sorted(unknown)[0]}", d[sorted(unknown)[0]], f"keys {names} for type {kind!r}")
    missing = set(names) - set(d)
    if missing:
        raise ValueError(f"{where}.{sorted(missing)[0]} is missing: a {kind} needs {names}")
    if cls is Difference:
        d["base"] = geometry_from_dict(d["base"], f"{where}.base")
        minus = d["minus"] if isinstance(d["minus"], (list, tuple)) else [d["minus"]]
        d["minus"] = tuple(geometry_from_dict(part, f"{where}.minus[{i}]") for i, part in enumerate(minus))
    try:
        return cls(**d)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


# ----------------------------------------------------------------------------------- grid
@dataclass(frozen=True)
class Grid:
    """Fixed Cartesian grid: `cells` per axis, spacing `h` (m), lower corner `origin` (m).

    Nodes per axis are cells + 1; the domain is [origin, origin + cells * h].
    """

    cells: tuple[int, ...]
    h: float
    origin: tuple[float, ...] | None = None

    def __post_init__(self):
        cells = self.cells
        if is_integer(cells):
            cells = (cells,)
        try:
            ok = not isinstance(cells, (str, bytes)) and all(is_integer(c) for c in cells)
        except TypeError:
            ok = False
        if not ok or not 1 <= len(tuple(cells)) <= 3:
            fail("grid.cells", self.cells, "a list of 1 to 3 integers")
        cells = tuple(int(c) for c in cells)
        for d, c in enumerate(cells):
            if c < 2:
                fail(f"grid.cells[{d}]", c, ">= 2")
        object.__setattr__(self, "cells", cells)
        h = as_float("grid.h", self.h)
        if not h > 0:
            fail("grid.h", h, "> 0 m")
        object.__setattr__(self, "h", h)
        origin = (0.0,) * len(cells) if self.origin is None else self.origin
        object.__setattr__(self, "origin", as_floats("grid.origin", origin, len(cells)))

    @property
    def dim(self) -> int:
        return len(self.cells)

    @property
    def nodes(self) -> tuple[int, ...]:
        return tuple(c + 1 for c in self.cells)

    @property
    def n_nodes(self) -> int:
        return math.prod(self.nodes)

    @property
    def hi(self) -> tuple[float, ...]:
        return tuple(o + c * self.h for o, c in zip(self.origin, self.cells))

    def to_dict(self) -> dict[str, Any]:
        return {"cells": list(self.cells), "h": self.h, "origin": list(self.origin)}
