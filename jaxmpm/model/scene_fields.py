"""SceneFields: the fields of a Scene and the static facts derived from them, without the checks
that run when a Scene is built. The checks (`scene_checks`, `sampling`, `memory`) take a
SceneFields, so they sit below `scene.py`, which composes them into `Scene`."""

from __future__ import annotations

from dataclasses import dataclass, field

from jaxmpm.materials import Material, resolve_material
from jaxmpm.model.geometry import Grid
from jaxmpm.model.parts import DENSITY_DIFFUSION, FLUID_VISCOSITY, Boundary, Phase, is_fluid


@dataclass(frozen=True)
class SceneFields:
    """The fields of `jaxmpm.Scene` (documented there) and their derived static facts; built only
    as a Scene, which validates them."""

    grid: Grid
    phases: tuple[Phase, ...]
    materials: tuple[Material, ...] = ()
    shape: str = "ddmp"
    transfer: str = "musl"
    energy_update: str = "midpoint"
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
    density_diffusion: float = DENSITY_DIFFUSION
    ambient_pressure: float | None = None
    axisymmetric: bool = False
    boundary: Boundary = field(default_factory=Boundary)
    cfl: float = 0.3
    t_end: float = 1e-3
    n_out: int = 10
    name: str = "scene"
    description: str = ""
    window: tuple[int, ...] | None = None

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
    def continuity_possible(self) -> bool:
        """Whether the continuity form (E7) can be on: interface forces and transfer = 'musl'."""
        return self.has_interface_forces and self.transfer == "musl"

    @property
    def continuity_form(self) -> str:
        """The continuity form the step uses (E7): 'transport' or 'off'. 'auto' gives 'transport'
        wherever the scene can have it (>= 2 velocity fields with interface forces, transfer
        'musl'), else 'off'."""
        if self.continuity != "auto":
            return self.continuity
        return "transport" if self.continuity_possible else "off"

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
