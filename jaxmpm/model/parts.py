"""The parts of a Scene other than its geometry: its phases (`Phase`), the walls (`Boundary`), the
names a scene may choose among (shape functions, transfers, wall kinds, ...) and which model kinds
are fluids.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from jaxmpm.materials.models import model_of, split_model
from jaxmpm.model.geometry import (
    GEOMETRIES,
)
from jaxmpm.model.geometry import (
    as_float as _float,
)
from jaxmpm.model.geometry import (
    as_floats as _floats,
)
from jaxmpm.model.geometry import (
    fail as _fail,
)
from jaxmpm.model.geometry import (
    is_integer as _is_integer,
)

SHAPES = ("linear", "ddmp", "bspline2")
TRANSFERS = ("musl", "seed", "seed_halfstep", "apic")
ENERGY_UPDATES = ("midpoint", "compatible")
BOUNDARIES = ("free", "slip", "separating", "fixed")
AXES = "xyz"
MAX_PPC = 8  # particles per cell per axis, at most
FLUID_VISCOSITY = (0.5, 2.0)  # (c_linear, c_quadratic) of the fluid phases' default artificial viscosity
# delta of the fluids' density diffusion (Scene.density_diffusion): delta-SPH's value (Antuono et al.
# 2010, Comput. Phys. Commun. 181, 532), whose density diffusion term it is
DENSITY_DIFFUSION = 0.1


def is_fluid(model_name: str) -> bool:
    """Whether a model kind has no shear strength: 'linear_fluid' or an equation of state alone
    (a hydrocode composition without a strength part: tait, ideal_gas, stiffened_gas, ...)."""
    if model_name == "linear_fluid":
        return True
    model = model_of(model_name)
    if not model.hydro:
        return False
    return not split_model(model_name)[1]


# ----------------------------------------------------------------------------------- phases
@dataclass(frozen=True)
class Phase:
    """One material (phase) of the scene.

    name: unique label. material: a library key (see `jaxmpm.materials.known_keys()`), a key of the
    scene's own `materials`, or a `Material`. geometry: Box, Sphere or Difference. velocity: initial velocity
    (m/s). field: index of the velocity field the phase moves with (phases in one field share the
    grid velocity). ppc: particles per cell per axis. fraction: initial volume fraction of the phase
    where it is (in (0, 1]; < 1 for interpenetrating mixtures): scales particle volume and mass.
    """

    name: str
    material: Any
    geometry: Any
    velocity: tuple[float, ...] | None = None
    field: int = 0
    ppc: int = 2
    fraction: float = 1.0

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.isidentifier():
            _fail("phase.name", self.name, "an identifier (letters, digits, underscore)")
        if not isinstance(self.geometry, tuple(GEOMETRIES.values())):
            _fail(f"phase.{self.name}.geometry", self.geometry, "Box, Sphere or Difference")
        dim = len(self.geometry.lo)
        v = (0.0,) * dim if self.velocity is None else self.velocity
        object.__setattr__(self, "velocity", _floats(f"phase.{self.name}.velocity", v, dim))
        if not _is_integer(self.field) or self.field < 0:
            _fail(f"phase.{self.name}.field", self.field, "an integer >= 0")
        if not _is_integer(self.ppc) or not 1 <= self.ppc <= MAX_PPC:
            _fail(f"phase.{self.name}.ppc", self.ppc, f"an integer in [1, {MAX_PPC}]")
        object.__setattr__(self, "field", int(self.field))
        object.__setattr__(self, "ppc", int(self.ppc))
        frac = _float(f"phase.{self.name}.fraction", self.fraction)
        if not 0 < frac <= 1:
            _fail(f"phase.{self.name}.fraction", frac, "(0, 1]")
        object.__setattr__(self, "fraction", frac)

    def to_dict(self) -> dict[str, Any]:
        mat = self.material if isinstance(self.material, str) else self.material.key
        return {
            "name": self.name,
            "material": mat,
            "field": self.field,
            "ppc": self.ppc,
            "fraction": self.fraction,
            "velocity": list(self.velocity),
            "geometry": self.geometry.to_dict(),
        }


@dataclass(frozen=True)
class Boundary:
    """Boundary condition on each face of the grid: 'free', 'slip' (normal velocity zero),
    'separating' (slip, but the material may leave the wall: only the normal velocity into the
    wall is zeroed, the peers' mpm88 condition) or 'fixed' (velocity zero). `layers` is the number
    of node layers a condition applies to. A 'slip' face is also a mirror plane: a body may be
    given whole across it (a sphere centred on it), and only its part inside the grid is sampled,
    so a symmetric 3D problem runs on a half or a quarter of its domain."""

    faces: tuple[tuple[str, str], ...] = ()
    layers: int = 1

    def __post_init__(self):
        if isinstance(self.faces, Mapping):
            pairs = list(self.faces.items())
        else:
            try:
                pairs = [tuple(f) for f in self.faces] if not isinstance(self.faces, (str, bytes)) else None
            except TypeError:
                pairs = None
            if pairs is None or any(len(f) != 2 or isinstance(f[0], str) and len(f[0]) == 1 for f in pairs):
                _fail("boundary.faces", self.faces, "pairs (face, kind), e.g. (('y_lo', 'fixed'),), or a dict")
        names = [k for k, _ in pairs]
        for k in names:
            if names.count(k) > 1:
                _fail(f"boundary.{k}", [v for n, v in pairs if n == k], "one condition per face (it is given twice)")
        faces = dict(pairs)
        for k, v in faces.items():
            if k not in FACE_NAMES:
                _fail(f"boundary.{k}", v, f"face names {FACE_NAMES}")
            if v not in BOUNDARIES:
                _fail(f"boundary.{k}", v, " | ".join(BOUNDARIES))
        object.__setattr__(self, "faces", tuple(sorted(faces.items())))
        if not isinstance(self.layers, int) or isinstance(self.layers, bool) or not 1 <= self.layers <= 4:
            _fail("boundary.layers", self.layers, "an integer in [1, 4]")

    def kind(self, axis: int, side: str) -> str:
        return dict(self.faces).get(f"{AXES[axis]}_{side}", "free")


FRAGMENTATION = ("failed", "plastic", "tensile")
CONTINUITY = ("auto", "off", "transport")
FACE_NAMES = tuple(f"{a}_{s}" for a in AXES for s in ("lo", "hi"))
