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
from dataclasses import dataclass
from typing import Any

# the geometry and the scene's parts live in jaxmpm.model.geometry and jaxmpm.model.parts; their
# names stay importable from here
from jaxmpm.model.geometry import (
    GEOMETRIES as GEOMETRIES,
)
from jaxmpm.model.geometry import (
    Box as Box,
)
from jaxmpm.model.geometry import (
    Difference as Difference,
)
from jaxmpm.model.geometry import (
    Grid as Grid,
)
from jaxmpm.model.geometry import (
    Sphere as Sphere,
)
from jaxmpm.model.geometry import (
    geometry_from_dict as geometry_from_dict,
)
from jaxmpm.model.memory import check_scene_memory
from jaxmpm.model.parts import (
    AXES as AXES,
)
from jaxmpm.model.parts import (
    BOUNDARIES as BOUNDARIES,
)
from jaxmpm.model.parts import (
    CONTINUITY as CONTINUITY,
)
from jaxmpm.model.parts import (
    DENSITY_DIFFUSION as DENSITY_DIFFUSION,
)
from jaxmpm.model.parts import (
    FLUID_VISCOSITY as FLUID_VISCOSITY,
)
from jaxmpm.model.parts import (
    Boundary as Boundary,
)
from jaxmpm.model.parts import (
    Phase as Phase,
)
from jaxmpm.model.parts import (
    is_fluid as is_fluid,
)
from jaxmpm.model.parts import (
    FACE_NAMES as FACE_NAMES,
)
from jaxmpm.model.parts import (
    FRAGMENTATION as FRAGMENTATION,
)
from jaxmpm.model.parts import (
    MAX_PPC as MAX_PPC,
)
from jaxmpm.model.parts import (
    SHAPES as SHAPES,
)
from jaxmpm.model.parts import (
    TRANSFERS as TRANSFERS,
)
from jaxmpm.model.sampling import check_sampling
from jaxmpm.model.scene_fields import SceneFields
from jaxmpm.model.scene_checks import check_scene_fields


# ----------------------------------------------------------------------------------- scene
@dataclass(frozen=True)
class Scene(SceneFields):
    """Static description of a simulation. Hashable; validated at construction.

    Fields:
      grid: Grid. phases: tuple of Phase. materials: user materials by key (tuple of Material).
      shape: 'ddmp' (default; linear hat with the DDMP gradient, PHYSICS 2.2), 'linear' (standard MPM)
        or 'bspline2' (quadratic B-spline). transfer: 'musl' (default: the seed's update with the
        remap done at the step's own positions), 'seed' (remap at the new positions),
        'seed_halfstep' (the seed's literal half-step position term) -- see jaxmpm.step.seed_update
        for what each does and measures -- or 'apic' (affine PIC / MLS, requires 'bspline2').
      energy_update: how the hydrocode models' internal energy takes the step's work. 'midpoint'
        (default): the midpoint stress on the end-of-step rate, second order along an isentrope,
        but a strong impact gains energy. 'compatible': the work the grid's forces did (the start
        stress on the midpoint velocity's rate), so the total energy is exact for every step, and
        a shocked state's energy carries a bias of the order of the CFL number (docs/physics.md).
        Only with transfer = 'musl'. The total-stress kinds take the midpoint work with either.
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
      density_diffusion: delta (dimensionless, in [0, 1]; default DENSITY_DIFFUSION = 0.1, 0: off)
        of the density diffusion that barotropic fluid phases take with DDMP and 'musl' (the
        delta-SPH term on the grid: each particle's specific volume relaxes to its phase's local
        average at the rate delta c / h; jaxmpm.stages.density_diffusion). It removes DDMP's
        particle pressure noise and dissipates: docs/verification.md.
      ambient_pressure: the pressure of the surroundings p_a (Pa, >= 0), or None (default: 0 Pa,
        nothing traced). The void around the material holds p_a, so the grid sees every particle's
        stress as the gauge stress sigma + p_a I and the fields' common pressure as p - p_a (E2:
        a uniform pressure has no divergence inside the material, and the surroundings' p_a
        cancels its traction at a free surface; walls take theirs): a body at p_a beside the
        void stays at rest, and the force of the particles' own pressure no longer depends, in
        proportion to p_a, on where they sit in their cells. Why: a gas at an ambient pressure
        in a box grows from round-off with the absolute stress (air at 1 atm, 16 x 16 cells of
        5.7 mm, DDMP: from 1e-9 to 21 m/s in 2 ms), not with the gauge (docs/limitations.md).
        The conserved energy then holds the surroundings' p_a sum_p V_p (`diagnostics.total_energy`).
        Not with the closure (effects.c_h), whose fragments relax to the pressure of the void.
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

    def __post_init__(self):
        check_scene_fields(self)  # jaxmpm.model.scene_checks: each field, in order
        # before sampling (grid at float32, the least a run holds): refused, not swapped
        check_scene_memory(self, itemsize=4)
        check_sampling(self)  # every phase has particles, all inside the grid's usable region

    def replace(self, **changes: Any) -> "Scene":
        return dataclasses.replace(self, **changes)
