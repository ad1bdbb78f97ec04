"""The allowed values of the built-in scenes' builder options: one table per builder (a function of
the options given, since a floor can depend on another option), used both by the builder's checks
(`check`) and by `jaxmpm scenes --verbose` / `jaxmpm scenes NAME` (`describe`)."""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(frozen=True)
class Range:
    """An option's allowed values: `words` says them, `contains(value)` tests one."""

    words: str
    contains: Callable[[Any], bool]


def _real(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def number(low: float = 0.0, *, strict: bool = True, unit: str = "", note: str = "") -> Range:
    """A finite number > low (strict) or >= low."""
    op = ">" if strict else ">="
    words = f"a finite number {op} {low:.3g}" + (f" {unit}" if unit else "") + (f" ({note})" if note else "")
    return Range(words, lambda v: _real(v) and (v > low if strict else v >= low))


def optional(r: Range, default_words: str) -> Range:
    """A value of `r`, or None (not given: the builder's own default, `default_words`)."""
    return Range(f"{r.words}; not given: {default_words}", lambda v: v is None or r.contains(v))


def integer(least: int, note: str = "") -> Range:
    """An integer >= least."""
    return Range(
        f"an integer >= {least}" + (f" ({note})" if note else ""),
        lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= least,
    )


def choice(*values: float | str) -> Range:
    """One of `values` (numbers or names)."""
    words = " | ".join(("true" if v else "false") if isinstance(v, bool) else str(v) for v in values)
    return Range(words, lambda v: any(v == c and isinstance(v, bool) == isinstance(c, bool) for c in values))


FLAG = choice(True, False)


def cells_floor(resolution_per_cell: float, least_cells: int) -> float:
    """The smallest resolution that lays `least_cells` cells across a length that holds
    `resolution_per_cell` cells at resolution 1."""
    return least_cells / resolution_per_cell


def resolution(floor: float, cells: int, across: str) -> Range:
    """The `resolution` option: a finite number >= floor, which lays `cells` cells across `across`."""
    r = number(floor * (1 - 1e-12), strict=False)
    return Range(f"a finite number >= {floor:.3g} ({cells} cells across {across})", r.contains)


def check(scene: str, ranges: dict[str, Range], values: dict[str, Any]) -> None:
    """ValueError naming the scene, the first option outside its range and the allowed values."""
    for name, r in ranges.items():
        if name in values and not r.contains(values[name]):
            raise ValueError(f"{scene}: {name} = {values[name]!r} is invalid: allowed {r.words}")


def builder_options(build: Callable[..., Any]) -> dict:
    """{name: inspect.Parameter} of the options a built-in scene's builder takes by name."""
    params = inspect.signature(build).parameters
    return {p: v for p, v in params.items() if v.kind in (v.POSITIONAL_OR_KEYWORD, v.KEYWORD_ONLY)}
