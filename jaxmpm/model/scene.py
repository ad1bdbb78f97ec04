"""Scene: the static description of a simulation (what is simulated).

A `Scene` fixes the shape of the computation: dimension, grid, phases (material model kinds,
geometry, particle counts), velocity fields, effects, boundary conditions, shape function and
transfer scheme. It is frozen, hashable and validated when built: every error is a `ValueError`
that names the field, the value and the allowed range. The numbers a user may calibrate or batch
(moduli, densities, gravity, CFL, ...) are copied from the scene into `Params` by
`jaxmpm.default_params`; the scene keeps only their defaults. SI units throughout.

Scenes are built in Python or read from TOML (`jaxmpm.load_scene`), and written back to TOML
(`scene_to_toml`) so every output file says how to reproduce it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

# the geometry lives in jaxmpm.model.geometry; its names stay importable from here
from jaxmpm.model.geometry import (
    GEOMETRIES,
    Box as Box,
    Difference as Difference,
    Grid as Grid,
    Sphere as Sphere,
    fail as _fail,
    as_float as _float,
    as_floats as _floats,
    is_integer as _is_integer,
    geometry_from_dict as geometry_from_dict,
)
from jaxmpm.materials import Material, resolve_material
from jaxmpm.materials.models import model_of, split_model
from jaxmpm.model.memory import check_scene_memory
from jaxmpm.model.numbers import NUMBERS
from jaxmpm.model.sampling import check_sampling

SHAPES = ("linear", "ddmp", "bspline2")
TRANSFERS = ("musl", "seed", "seed_halfstep", "apic")
BOUNDARIES = ("free", "slip", "fixed")
AXES = "xyz"
MAX_PPC = 8  # particles per cell per axis, at most
FLUID_VISCOSITY = (0.5, 2.0)  # (c_linear, c_quadratic) of the fluid phases' default artificial viscosity


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

    def to_dict(self):
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
    """Boundary condition on each face of the grid: 'free', 'slip' (normal velocity zero) or
    'fixed' (velocity zero). `layers` is the number of node layers a condition applies to."""

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


# ----------------------------------------------------------------------------------- scene
@dataclass(frozen=True)
class Scene:
    """Static description of a simulation. Hashable; validated at construction.

    Fields:
      grid: Grid. phases: tuple of Phase. materials: user materials by key (tuple of Material).
      shape: 'ddmp' (default; linear hat with the DDMP gradient, PHYSICS 2.2), 'linear' (standard MPM)
        or 'bspline2' (quadratic B-spline). transfer: 'musl' (default: the seed's update with the
        remap done at the step's own positions), 'seed' (remap at the new positions),
        'seed_halfstep' (the seed's literal half-step position term) -- see jaxmpm.step.seed_update
        for what each does and measures -- or 'apic' (affine PIC / MLS, requires 'bspline2').
      gravity: gravity acceleration (m/s^2, one per axis), or None for no gravity term.
      gravity_ramp: time (s) over which gravity is ramped smoothly from 0 (0: no ramp).
      damping: mass-proportional nodal damping rate (1/s), or None for no damping term.
      body_force: True to give each phase a constant body acceleration Param (m/s^2).
      drag: exchange drag coefficient C_d of (E3) between velocity fields, or None for no quadratic
        drag. drag_length: the length d of (E3) in m (None: the cell size h). linear_drag: K_lin of
        the optional linear term in kg/(m^3 s), or None. interface_forces: the common-pressure
        interface forces of (E13, E6, E15) between fields (on by default; only with >= 2 fields);
        a list of field indices: only those fields share the common pressure, the others are
        coupled by the drag alone (a light gas beside loaded solids: rod_penetration).
        drag_heating: book the work the exchange's drag (E3) dissipates as internal energy of the
        fields' particles (our closure, off by default; only with transfer = 'musl'): each pair's
        work J_kj . (v_k - v_j) at the remapped velocities, split as if the interface moved with
        the pair's centre of mass (the lighter field heats more); a particle takes its field's
        nodal heat per unit mass, weighted by S_np (jaxmpm.stages.fields.drag_heat). Without it the
        drag's dissipation leaves the energy balance (the coarse 2-field debris cloud loses 3%).
      continuity: the continuity form of (E7) between the fields that share the common pressure:
        'transport' (the fields resist overlapping: each phase takes its compressibility share of
        the volume that the interface forces' motion closes, the exact transpose of those forces,
        so that their work is stored; jaxmpm.stages.multifield.continuity_volume_rate), 'off', or 'auto'
        (default: 'transport' wherever the scene has interface forces and transfer = 'musl', else
        'off'). 'transport' only with interface forces and transfer = 'musl'.
      c_h: the plastic-strain scale C_h of the continuous-to-disperse closure (E4, E5, E8), or None
        for no closure (material volume follows the velocity divergence).
      fragmentation: what the closure counts as fragmented (only with c_h). 'failed' (default):
        in a phase whose model has a failure part (spall, Johnson-Cook failure, ...) alpha =
        1 - D tanh(eps_ps / C_h), D in [0, 1] its damage, so the plastic strain of intact material
        (a shock's) is not fragmentation; phases without a failure model use the seed's alpha.
        'plastic': the seed's alpha = 1 - tanh(eps_ps / C_h) for every phase (jaxmpm.stages.constitutive).
        'tensile': only plastic strain accrued in tension (p < 0) fragments, alpha = 1 - D with
        D = tanh(eps_t / C_h) held in the State's damage, and alpha acts on tension only (compressive
        pressure kept): a shock is untouched (docs/closure.md).
      artificial_viscosity: (c_linear, c_quadratic) of the von Neumann-Richtmyer shock viscosity
        q = rho h (c_q h (tr D)^2 - c_l c tr D) in compression (the defaults of
        Params.artificial_viscosity) for every phase; only with equation-of-state (hydrocode) models. None
        (default): FLUID_VISCOSITY = (0.5, 2.0) for the fluid phases (no shear strength:
        `is_fluid`) with the FLIP-like transfers ('musl', 'seed', 'seed_halfstep'), none for the
        other phases and with 'apic'. (0, 0): none at all. Why: without it a free-surface flow
        hitting a wall gains energy without bound under 'musl' (tests/test_fluids.py's dam break,
        10 cells per column width, float64: +0.5% of m g a by T = 5, +1.7% by T = 6; 20 cells,
        float32: +93% by T = 7); with it the energy only falls, by the same 4e-4 m g a as without
        before the impact (T = 2). The peers' mpm88 with linear shapes and 'musl' went non-finite at
        the peers' step without it and is stable with it. See `viscous_phases`.
      axisymmetric: 2D axisymmetric (r, z) geometry (PHYSICS 2.3): axis 0 is the radius r >= 0
        (grid.origin[0] >= 0), axis 1 the axial coordinate z. Volumes and masses are per radian
        (V = r dr dz), the stress has a hoop component (stress and F are 3x3, the third axis theta)
        and the grid force a hoop term; on the axis (r = 0) v_r = 0 whatever boundary.x_lo says.
      window: None (default) or the cells per axis (d ints) of a block on which the per-field grid
        operators are computed instead of on the whole grid: each velocity field's DDMP operators
        (R1-R3, E11-E13) on a block placed every step at the field's first occupied cell, the
        exchange (E3, E14) on a block placed on the nodes that two or more fields share. Outside
        these blocks the operators are zero, so the results are those of the whole grid (to
        round-off) at the cost of the blocks: for fields that each cover a small part of the grid
        (benchmarks/multifield_cost.py; `ddmp.fitting_window` picks one from an initial state).
        A step in which a field's particles (or the shared nodes) span more than the block is
        computed on the whole grid. Leave it None for ensembles under vmap: there both ways are
        computed every step.
      boundary: Boundary. cfl: Courant number in (0, 1]. t_end: default end time (s). n_out: outputs.
    """

    grid: Grid
    phases: tuple[Phase, ...]
    materials: tuple[Material, ...] = ()
    shape: str = "ddmp"
    transfer: str = "musl"
    gravity: tuple[float, ...] | None = None
    gravity_ramp: float = 0.0
    damping: float | None = None
    body_force: bool = False
    drag: float | None = None
    drag_length: float | None = None
    linear_drag: float | None = None
    drag_heating: bool = False
    interface_forces: bool = True
    continuity: str = "auto"
    c_h: float | None = None
    fragmentation: str = "failed"
    artificial_viscosity: tuple[float, float] | None = None
    axisymmetric: bool = False
    boundary: Boundary = field(default_factory=Boundary)
    cfl: float = 0.3
    t_end: float = 1e-3
    n_out: int = 10
    name: str = "scene"
    description: str = ""
    window: tuple[int, ...] | None = None

    def __post_init__(self):
        self._check_parts()
        self._check_phases()
        self._check_materials()
        self._check_scheme()
        self._check_numbers()
        self._check_viscous_models()
        self._check_axisymmetric()
        self._check_window_shape()
        self._check_couplings()
        self._check_boundary()
        self._check_run()
        self._check_drag_heating()
        self._check_window_use()
        check_scene_memory(
            self, itemsize=4
        )  # before sampling (grid at float32, the least a run holds): refused, not swapped
        check_sampling(self)  # every phase has particles, all inside the grid's usable region

    # each check raises the project's ValueError naming the field (jaxmpm.model.geometry.fail) and
    # stores the normalised value (tuples, floats); they run in this order, each relying on those before
    def _check_parts(self):
        """The grid, the phases and materials (tuples of Phase and Material), name and description."""
        if not isinstance(self.grid, Grid):
            _fail("grid", self.grid, "a Grid")
        for name, kind in (("phases", Phase), ("materials", Material)):
            items = getattr(self, name)
            if (
                isinstance(items, (str, bytes, Phase, Material))
                or not isinstance(items, Iterable)
                or not all(isinstance(x, kind) for x in items)
            ):
                _fail(name, items, f"a tuple of {kind.__name__}")
        for name in ("name", "description"):
            if not isinstance(getattr(self, name), str):
                _fail(name, getattr(self, name), "a string")
        if not tuple(self.phases):
            _fail("phase", tuple(self.phases), "at least one [[phase]]")
        object.__setattr__(self, "phases", tuple(self.phases))
        object.__setattr__(self, "materials", tuple(self.materials))

    def _check_phases(self):
        """Unique phase names, each body inside the grid, velocity fields numbered without gaps."""
        dim = self.grid.dim
        names = [p.name for p in self.phases]
        for n in names:
            if names.count(n) > 1:
                _fail("phase.name", n, "unique names (two phases share it)")
        for p in self.phases:
            if len(p.geometry.lo) != dim:
                _fail(f"phase.{p.name}.geometry", p.geometry.to_dict(), f"{dim} coordinates per point (grid is {dim}D)")
            for d in range(dim):
                lo, hi = self.grid.origin[d], self.grid.hi[d]
                if d == 0 and self.axisymmetric is True and lo == 0.0:
                    lo = -hi  # a body on the axis may be given whole (a sphere centred at r = 0)
                if p.geometry.lo[d] < lo - 1e-12 * abs(hi - lo) or p.geometry.hi[d] > hi + 1e-12 * abs(hi - lo):
                    _fail(
                        f"phase.{p.name}.geometry",
                        p.geometry.to_dict(),
                        f"inside the grid: axis {AXES[d]} in [{lo}, {hi}] m (a particle would lie outside the grid)",
                    )
        fields = sorted({p.field for p in self.phases})
        if fields != list(range(len(fields))):
            bad = [p for p in self.phases if p.field >= len(fields)][0]
            _fail(f"phase.{bad.name}.field", bad.field, f"fields numbered 0..{len(fields) - 1} without gaps")

    def _check_materials(self):
        """Unique material keys; every phase's material resolves (an unknown key fails here, listing
        the known ones), one material per key (a scene file names a material by its key alone)."""
        keys = [m.key for m in self.materials]
        for k in keys:
            if keys.count(k) > 1:
                _fail("materials", k, "unique material keys")
        by_key = {m.key: ("materials", m) for m in self.materials}
        for p in self.phases:
            m = resolve_material(p.material, self.materials, f"phase.{p.name}.material")
            where, other = by_key.setdefault(m.key, (f"phase.{p.name}", m))
            if other != m:
                _fail(
                    f"phase.{p.name}.material",
                    m.key,
                    f"one material per key: {where} has another material of key {m.key!r} (rename one)",
                )

    def _check_scheme(self):
        """The shape function and the transfer scheme, and that 'apic' has B-splines."""
        if self.shape not in SHAPES:
            _fail("shape", self.shape, " | ".join(SHAPES))
        if self.transfer not in TRANSFERS:
            _fail("transfer", self.transfer, " | ".join(TRANSFERS))
        if self.transfer == "apic" and self.shape != "bspline2":
            _fail("transfer", self.transfer, "'apic' only with shape = 'bspline2'")

    def _check_numbers(self):
        """The effects' numbers and cfl, from the table of jaxmpm.model.numbers: each in its range,
        and those that only act with another effect (gravity_ramp, drag_length) only with it."""
        for n in NUMBERS:
            value = getattr(self, n.name)
            if value is not None:
                object.__setattr__(self, n.name, n.check_scene_value(value, self.grid.dim))
        for n in NUMBERS:
            value, switch = getattr(self, n.name), n.switch_attribute
            if switch and switch != n.name and value not in (None, n.default) and getattr(self, switch) is None:
                _fail(n.key, value, f"only with effects.{switch} ({n.role})")
        if not isinstance(self.body_force, bool):
            _fail("effects.body_force", self.body_force, "true | false")

    def _check_viscous_models(self):
        """An artificial viscosity given for every phase only where each has an equation of state
        (or is a linear_fluid, which recomputes its stress from F each step: a q does not accumulate)."""
        if self.artificial_viscosity is None:
            return
        for p in self.phases:
            m = self.material(p)
            if not (model_of(m.model).hydro or is_fluid(m.model)):
                _fail(
                    "effects.artificial_viscosity",
                    list(self.artificial_viscosity),
                    f"only with equation-of-state models and linear_fluid: phase {p.name!r} uses {m.model!r}",
                )

    def _check_axisymmetric(self):
        """Axisymmetric: a 2D (r, z) grid at r >= 0, with the shapes and updates that have a hoop term."""
        if not isinstance(self.axisymmetric, bool):
            _fail("axisymmetric", self.axisymmetric, "true | false")
        if not self.axisymmetric:
            return
        if self.dim != 2:
            _fail("axisymmetric", True, f"only with a 2D (r, z) grid (grid is {self.dim}D)")
        if self.grid.origin[0] < 0:
            _fail("grid.origin[0]", self.grid.origin[0], ">= 0 m (the radius of an axisymmetric grid)")
        if self.shape == "bspline2" or self.transfer == "apic":
            _fail("axisymmetric", True, "only with shape 'ddmp' or 'linear' and the musl / seed updates")

    def _check_window_shape(self):
        """A window is d cell counts, each within the grid's."""
        if self.window is None:
            return
        w, dim = self.window, self.dim
        ok = (
            isinstance(w, (tuple, list))
            and len(w) == dim
            and all(_is_integer(c) and 1 <= c <= n for c, n in zip(w, self.grid.cells))
        )
        if not ok:
            _fail("window", w, f"None or {dim} integers, cells per axis in 1..grid.cells = {list(self.grid.cells)}")
        object.__setattr__(self, "window", tuple(int(c) for c in w))

    def _check_couplings(self):
        """Interface forces (all fields, or a list of >= 2), the continuity form, the closure's
        fragmentation, and the schemes that several fields and the closure need."""
        if not isinstance(self.interface_forces, bool):
            try:
                sub = tuple(sorted(set(int(k) for k in self.interface_forces)))
                ok = all(_is_integer(k) for k in self.interface_forces)
            except (TypeError, ValueError):
                ok = False
            if not ok or len(sub) < 2 or not all(0 <= k < self.n_fields for k in sub):
                _fail(
                    "effects.interface_forces",
                    self.interface_forces,
                    f"true | false | a list of >= 2 velocity fields in 0..{self.n_fields - 1} that share the common pressure",
                )
            object.__setattr__(self, "interface_forces", True if len(sub) == self.n_fields else sub)
        if self.continuity not in CONTINUITY:
            _fail("effects.continuity", self.continuity, " | ".join(repr(c) for c in CONTINUITY))
        if self.continuity == "transport" and not self._continuity_possible:
            _fail(
                "effects.continuity",
                self.continuity,
                "'auto' | 'off' unless the scene has >= 2 velocity fields with interface forces and transfer = 'musl'",
            )
        if self.fragmentation not in FRAGMENTATION:
            _fail("effects.fragmentation", self.fragmentation, " | ".join(repr(f) for f in FRAGMENTATION))
        if self.has_closure and self.transfer == "apic":
            _fail("effects.c_h", self.c_h, "only with the musl / seed updates (not with transfer = 'apic')")
        if self.n_fields > 1 and (self.shape == "bspline2" or self.transfer == "apic"):
            _fail("shape", self.shape, "'ddmp' or 'linear' (not apic) when phases use several velocity fields")

    def _check_boundary(self):
        """A Boundary whose faces are the grid's, with fewer wall layers than the grid has cells."""
        if not isinstance(self.boundary, Boundary):
            _fail("boundary", self.boundary, "a Boundary")
        dim = self.dim
        for face, kind in self.boundary.faces:
            if AXES.index(face.split("_")[0]) >= dim:
                _fail(f"boundary.{face}", kind, f"faces of the {dim}D grid's axes {FACE_NAMES[: 2 * dim]}")
        for k in range(dim):
            sides = sum(self.boundary.kind(k, side) != "free" for side in ("lo", "hi"))
            if sides * self.boundary.layers > self.grid.cells[k]:
                _fail(
                    "boundary.layers",
                    self.boundary.layers,
                    f"at most {self.grid.cells[k] // sides} on axis {AXES[k]} ({self.grid.cells[k]} cells, walls on {sides} "
                    "side(s)): more would constrain every node of the axis",
                )

    def _check_run(self):
        """The default end time and number of outputs."""
        t_end = _float("t_end", self.t_end)
        if not t_end > 0:
            _fail("t_end", t_end, "> 0 s")
        object.__setattr__(self, "t_end", t_end)
        if not isinstance(self.n_out, int) or isinstance(self.n_out, bool) or self.n_out < 1:
            _fail("output.n_out", self.n_out, "an integer >= 1")

    def _check_drag_heating(self):
        """Drag heating needs an exchange to heat with and the 'musl' update."""
        if not isinstance(self.drag_heating, bool):
            _fail("effects.drag_heating", self.drag_heating, "true | false")
        if self.drag_heating and not self.has_exchange:
            _fail(
                "effects.drag_heating",
                self.drag_heating,
                "false unless the scene has an exchange (effects.drag or "
                "effects.linear_drag, and phases in two or more velocity fields)",
            )
        if self.drag_heating and self.transfer != "musl":
            _fail(
                "effects.drag_heating",
                self.drag_heating,
                "false unless transfer = 'musl' (the heat is the drag's work at the remap of the step's own positions)",
            )

    def _check_window_use(self):
        """A window only where the scene has per-field grid operators to compute on it."""
        if self.window is not None and self.shape != "ddmp" and not self.has_interface_forces and not self.has_exchange:
            _fail(
                "window",
                list(self.window),
                "None unless the scene has DDMP operators (shape 'ddmp', or interface "
                "forces between velocity fields) or an exchange between fields",
            )

    # ------------------------------------------------------------------ derived static facts
    @property
    def dim(self) -> int:
        return self.grid.dim

    @property
    def material_dim(self) -> int:
        """Dimension of F and the stress: 3 for axisymmetric scenes (r, z, theta), else dim."""
        return 3 if self.axisymmetric else self.dim

    @property
    def n_fields(self) -> int:
        return 1 + max(p.field for p in self.phases)

    @property
    def has_exchange(self) -> bool:
        """Whether the step traces the exchange force (E3): several fields and a drag term."""
        return self.n_fields > 1 and (self.drag is not None or self.linear_drag is not None)

    @property
    def has_closure(self) -> bool:
        """Whether the continuous-to-disperse closure (E4, E5, E8) is on: effects.c_h given. The one
        switch of jaxmpm.stages.closure."""
        return self.c_h is not None

    @property
    def has_interface_forces(self) -> bool:
        return self.n_fields > 1 and self.interface_forces is not False

    @property
    def _continuity_possible(self) -> bool:
        return self.has_interface_forces and self.transfer == "musl"

    @property
    def continuity_form(self) -> str:
        """The continuity form the step uses (E7): 'transport' or 'off'. 'auto' gives 'transport'
        wherever the scene can have it (>= 2 velocity fields with interface forces, transfer
        'musl'), else 'off'."""
        if self.continuity != "auto":
            return self.continuity
        return "transport" if self._continuity_possible else "off"

    @property
    def viscous_phases(self) -> tuple[bool, ...]:
        """Per phase: whether it takes the artificial viscosity (`viscosity`'s coefficients)."""
        if self.artificial_viscosity is not None:
            return (True,) * len(self.phases)
        if self.transfer == "apic":
            return (False,) * len(self.phases)
        return tuple(is_fluid(self.material(p).model) for p in self.phases)

    @property
    def viscosity(self) -> tuple[float, float] | None:
        """(c_linear, c_quadratic) of the artificial viscosity the step applies to `viscous_phases`,
        or None where no phase takes one: artificial_viscosity if given, else FLUID_VISCOSITY
        where a phase is a fluid (see the field's note)."""
        if self.artificial_viscosity is not None:
            return self.artificial_viscosity
        return FLUID_VISCOSITY if any(self.viscous_phases) else None

    @property
    def pressure_fields(self) -> tuple[int, ...]:
        """The velocity fields that share the common pressure and its interface forces (E6, E13)."""
        if not self.has_interface_forces:
            return ()
        return tuple(range(self.n_fields)) if self.interface_forces is True else tuple(self.interface_forces)

    def material(self, phase: Phase) -> Material:
        """The resolved Material of `phase` (library key, scene material or Material)."""
        return resolve_material(phase.material, self.materials, f"phase.{phase.name}.material")

    def phase_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.phases)

    def replace(self, **changes) -> "Scene":
        return dataclasses.replace(self, **changes)
