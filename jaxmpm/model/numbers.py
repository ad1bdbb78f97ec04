"""The numbers of a scene's effects: one table of their names, units, allowed ranges and defaults.

Each number has one name across `Scene` (its field), `Params` (its field), the scene file (its key
under `[effects]`, or at the top for `cfl`) and the command lines. `Params`' fields, the defaults
`default_params` gives them and the checks `check_params` runs on them, and `Scene`'s validation
of its effects, are all built from `NUMBERS`: a number is added (or its range changed) here alone.

    name                  unit         allowed        default (the Params value with the effect off)
    gravity               m/s^2        finite, (d,)   zeros
    gravity_ramp          s            >= 0           0 (no ramp)
    damping               1/s          >= 0           0
    cfl                   -            (0, 1]         0.3 (always read)
    drag                  -            >= 0           0: C_d of the exchange (E3)
    drag_length           m            > 0            the cell size h: d of (E3)
    linear_drag           kg/(m^3 s)   >= 0           0: K_lin of the linear drag term
    c_h                   -            > 0            1: C_h of the closure (E5)
    artificial_viscosity  -            >= 0, (2,)     (0, 0): (c_linear, c_quadratic) of the shock viscosity
    ambient_pressure      Pa           >= 0           0: the pressure of the surroundings (the stress gauge)

The names these numbers had in `Params` before (`drag_coefficient`, `av_linear`, `av_quadratic`)
are in `OLD_NAMES`: they still work for one release, with a DeprecationWarning naming the new one.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from jaxmpm.model.geometry import as_float, as_floats, fail


@dataclass(frozen=True)
class Number:
    """One number of the table.

    name: its one name (Scene field, Params field, scene-file key). unit: SI unit ('' where it has
    none). low, high, low_open, high_open: the allowed range of each value, e.g. (0, 1] is
    low = 0, low_open, high = 1. size: 0 for a number, 'd' for one per grid axis, 2 for a pair.
    default: the value Params holds where the scene's effect is off ('h': the cell size).
    scene_key: where the scene (and its file) spells it: 'effects.<name>', or 'cfl'. elements: what
    the entries of a pair are, for messages. source: the Scene attribute Params takes the value
    from (default: name). switch: the Scene attribute that is None where the effect is off
    (default: name; '' where the number is always read). off: what the scene lacks then, for messages.
    role: what it does, for the message that it acts only with its switch. params_text: what the
    Params check says is allowed where it words it otherwise than the scene's (damping's says finite).
    """

    name: str
    unit: str
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    size: int | str = 0
    default: Any = 0.0
    scene_key: str = ""
    elements: str = ""
    source: str = ""
    switch: str | None = None
    off: str = ""
    role: str = ""
    params_text: str = ""

    @property
    def scene_attribute(self) -> str:
        return self.source or self.name

    @property
    def switch_attribute(self) -> str:
        return self.name if self.switch is None else self.switch

    @property
    def key(self) -> str:
        return self.scene_key or f"effects.{self.name}"

    def range_text(self) -> str:
        """The allowed range of one value with its unit, as the errors say it: '>= 0 s', '(0, 1]'."""
        unit = f" {self.unit}" if self.unit else ""
        if math.isinf(self.low) and math.isinf(self.high):
            return f"finite{unit}"
        if math.isinf(self.high):
            return f"{'>' if self.low_open else '>='} {self.low:g}{unit}"
        lo, hi = ("(" if self.low_open else "["), (")" if self.high_open else "]")
        return f"{lo}{self.low:g}, {self.high:g}{hi}{unit}"

    def allowed(self, dim: int) -> str:
        """What the errors say is allowed: the range, and for a vector how many values."""
        if self.size == 0:
            return self.range_text()
        n = dim if self.size == "d" else self.size
        if math.isinf(self.low) and math.isinf(self.high):
            return f"{n} finite numbers ({self.unit}, one per axis)"
        return f"{n} numbers {self.range_text()} ({self.elements})"

    def admits(self, x: float) -> bool:
        """Whether one value lies in the range (a NaN does not)."""
        above = x > self.low if self.low_open else x >= self.low
        below = x < self.high if self.high_open else x <= self.high
        return bool(above and below and math.isfinite(x))

    def check_scene_value(self, value: Any, dim: int) -> float | tuple[float, ...]:
        """The scene's value as float(s), or a ValueError naming `key` and the allowed range."""
        if self.size == 0:
            x = as_float(self.key, value)
            if not self.admits(x):
                fail(self.key, x, self.allowed(dim))
            return x
        xs = as_floats(self.key, value, dim if self.size == "d" else self.size)
        if not all(self.admits(x) for x in xs):
            fail(self.key, list(xs), self.allowed(dim))
        return xs

    def check_params_value(self, value: Any, dim: int, label: str = "") -> None:
        """A concrete Params value in range, or a ValueError naming `params.<label or name>` and the range."""
        a = np.asarray(value, dtype=float)
        n = () if self.size == 0 else ((dim if self.size == "d" else self.size),)
        if a.shape != n or not all(self.admits(float(x)) for x in a.ravel()):
            shown = float(a) if a.ndim == 0 else a.tolist()
            allowed = self.params_text or self.allowed(dim)
            raise ValueError(f"params.{label or self.name} = {shown!r} is invalid: allowed {allowed}")


NUMBERS: tuple[Number, ...] = (
    Number("gravity", "m/s^2", size="d", off="gravity effect"),
    Number("gravity_ramp", "s", low=0.0, switch="gravity", off="gravity effect", role="it ramps gravity in"),
    Number("damping", "1/s", low=0.0, off="damping effect", params_text="finite values >= 0 1/s"),
    Number("cfl", "", low=0.0, high=1.0, low_open=True, default=0.3, scene_key="cfl", switch=""),
    Number("drag", "", low=0.0, off="drag"),
    Number(
        "drag_length",
        "m",
        low=0.0,
        low_open=True,
        default="h",
        switch="drag",
        off="drag",
        role="the length of its drag law, E3",
    ),
    Number("linear_drag", "kg/(m^3 s)", low=0.0, off="linear drag"),
    Number("c_h", "", low=0.0, low_open=True, default=1.0, off="closure (effects.c_h)"),
    Number(
        "artificial_viscosity",
        "",
        low=0.0,
        size=2,
        elements="[c_linear, c_quadratic]",
        source="viscosity",
        switch="viscosity",
        off="artificial viscosity",
    ),
    Number("ambient_pressure", "Pa", low=0.0, off="ambient pressure"),
)
BY_NAME = {n.name: n for n in NUMBERS}

# old Params names -> (new name, index into the new number or None)
OLD_NAMES: dict[str, tuple[str, int | None]] = {
    "drag_coefficient": ("drag", None),
    "av_linear": ("artificial_viscosity", 0),
    "av_quadratic": ("artificial_viscosity", 1),
}


def warn_old_name(old: str, stacklevel: int = 3) -> None:
    """The DeprecationWarning for an old Params name: it names the new one."""
    new, index = OLD_NAMES[old]
    where = f"params.{new}" if index is None else f"params.{new}[{index}]"
    warnings.warn(
        f"params.{old} is deprecated: it is {where} (one name with the scene's effects.{new}); "
        "the old name goes in the next release",
        DeprecationWarning,
        stacklevel=stacklevel,
    )
