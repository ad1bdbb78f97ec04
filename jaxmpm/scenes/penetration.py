"""Long-rod penetration (2D axisymmetric) and the Alekseevskii-Tate model it is checked against."""

# longer than 400 lines on purpose: three penetration scenes (long rod, sandwich target, projectile into concrete),
# each builder beside its options' ranges, its materials and its measures, and the Alekseevskii-Tate model the rod
# is checked against

from __future__ import annotations

import math

import jax
import numpy as np
from jax.typing import ArrayLike

from jaxmpm.materials import Material
from jaxmpm.materials.library import library_constants, library_material
from jaxmpm.model.sampling import sample_phase
from jaxmpm.model.scene import Boundary, Box, Difference, Grid, Phase, Scene
from jaxmpm.model.state import phase_slices
from jaxmpm.scenes import options
from jaxmpm.scenes.options import FLAG, choice, number, optional
from jaxmpm.model.state import State

ROD_DIAMETER, ROD_LENGTH, ROD_SPEED = 7.5e-3, 75e-3, 2000.0  # m, m (L/D = 10), m/s
REFERENCE_PLASTIC_STRAIN = 0.5


def flow_stress(key: str, eps_p: float = REFERENCE_PLASTIC_STRAIN) -> float:
    """Johnson-Cook flow stress A + B eps_p^n (Pa) of a library material at room temperature and the
    reference strain rate: the strength the Tate model's Y_p and R_t are built from."""
    c = library_constants(key)
    return c["A"] + c["B"] * eps_p ** c["n"]


def cavity_expansion_pressure(yield_stress: float, shear_modulus: float) -> float:
    """Quasi-static pressure (Pa) that expands a spherical cavity in an incompressible elastic-
    perfectly-plastic solid (Hill, The Mathematical Theory of Plasticity, 1950):
    p = (2/3) Y (1 + ln(2 G / Y)). Our estimate of Tate's target resistance R_t."""
    return 2.0 / 3.0 * yield_stress * (1.0 + math.log(2.0 * shear_modulus / yield_stress))


def tate_strengths(rod: str = "tungsten_wha", target: str = "steel_4340") -> tuple[float, float]:
    """(Y_p, R_t) in Pa for the Tate check: Y_p the rod's flow stress, R_t the target's cavity-
    expansion pressure at its flow stress, both at eps_p = 0.5 (tungsten_wha on steel_4340:
    Y_p = 1.67 GPa, R_t = 4.75 GPa)."""
    y_t = flow_stress(target)
    return flow_stress(rod), cavity_expansion_pressure(y_t, library_constants(target)["G"])


def tate_penetration_speed(v: ArrayLike, rho_p: float, rho_t: float, y_p: float, r_t: float) -> np.ndarray:
    """Steady penetration speed U (m/s) of an eroding rod at speed v (Alekseevskii 1966; Tate 1967):
    the interface stress balance 1/2 rho_p (v - U)^2 + Y_p = 1/2 rho_t U^2 + R_t solved for U,
    U = (v - sqrt(mu v^2 + (1 - mu) 2 (R_t - Y_p) / rho_p)) / (1 - mu), mu = rho_t / rho_p
    (U = v / (1 + sqrt(mu)) when R_t = Y_p), clipped at 0 where the target stops the rod."""
    v = np.asarray(v, float)
    mu = rho_t / rho_p
    disc = mu * v**2 + (1.0 - mu) * 2.0 * (r_t - y_p) / rho_p
    if abs(1.0 - mu) < 1e-12:
        u = 0.5 * v - (r_t - y_p) / (rho_p * v)
    else:
        u = (v - np.sqrt(np.maximum(disc, 0.0))) / (1.0 - mu)
    return np.maximum(u, 0.0)


def rod_penetration_ranges(diameter: float = ROD_DIAMETER, **_: object) -> dict:
    """The allowed values of `rod_penetration`'s options (2 cells across the rod's radius,
    D / 10 / resolution each; the target at least the rod's diameter given)."""
    d = diameter if number(0.0).contains(diameter) else ROD_DIAMETER
    least = number(d, strict=False, unit="m", note="the rod's diameter")
    return {
        "speed": number(0.0, unit="m/s"),
        "length": number(0.0, unit="m"),
        "diameter": number(0.0, unit="m"),
        "fields": choice(1, 2, 3),
        "air": FLAG,
        "drag": number(0.0),
        "target_radius": optional(least, "4 diameters"),
        "target_depth": optional(least, "speed t_end + 2 diameters"),
        "t_end": number(0.0, unit="s"),
        "resolution": options.resolution(options.cells_floor(5, 2), 2, "the rod's radius"),
    }


def rod_penetration(
    resolution: float = 1.0,
    speed: float = ROD_SPEED,
    length: float = ROD_LENGTH,
    diameter: float = ROD_DIAMETER,
    fields: int = 1,
    air: bool = False,
    drag: float = 1.0,
    target_radius: float | None = None,
    target_depth: float | None = None,
    t_end: float = 45e-6,
) -> Scene:
    """Long-rod penetration: a tungsten heavy-alloy rod (L/D = 10, D = 7.5 mm) hits semi-infinite
    steel end-on (the test series of Anderson, Hohler, Walker & Stilp, Int. J. Impact Eng. 16 (1995)
    1, at 1.5 to 3 km/s; the seed's multi-velocity impact).

    Geometry (2D axisymmetric, r >= 0, z along the flight): the rod (radius D/2, length `length`)
    stands one cell above the target's face z = 0 and moves along -z at `speed` (2000 m/s); the
    target fills r in [0, `target_radius`] (default 4 D) and z in [-`target_depth`, 0] (default
    speed * t_end + 2 D). Cells of D / 10 / resolution (5 across the rod's radius at resolution 1),
    2 x 2 particles per cell. Walls: slip on the outer radius, the target's back face and the top of the grid
    (which holds the air and stops the crater's ejecta).
    Phases: `rod` tungsten_wha and `target` steel_4340 from the library (Mie-Grueneisen EOS,
    Johnson-Cook strength with thermal softening, spall; the rod fails at a plastic strain of 0.25,
    the target by Johnson-Cook failure); with `air`, `air` at 1 atm fills the space above the
    target around the rod. `fields`: 1 (all in one velocity field), 2 (rod | target, coupled by
    drag C_d = `drag` and the common pressure; with `air`: rod and target | air), 3 (rod | target |
    air; needs `air`). The air is coupled to the solids by the drag alone (it takes no part in the
    common pressure: `Scene.interface_forces` lists the fields that do).
    Effects: artificial viscosity (0.5, 2.0).

    Measures (`penetration_measures`): penetration depth (the deepest rod material on the axis),
    the remaining rod length and the rod's tail speed against time; the steady penetration rate is
    checked against the Alekseevskii-Tate speed `tate_penetration_speed` at the tail speed, with
    Y_p and R_t from `tate_strengths` (1.67 and 4.75 GPa).

    Status: validated against Tate's model (not against the measured penetration depths). Measured
    (float64, slope of the depth over 13.5-45 us, U_tate at the tail speed, about 1950 m/s):
      resolution 0.5 (6100 particles, 10 s on 2 CPU cores): one field U = 1030, two 979 m/s; Tate 1047
      resolution 1.0 (24400 particles, 50 s):               one field U = 1072, two 1080 m/s; Tate 1048
    (two fields with the continuity form, the default; without it, 1020 and 1100 m/s).
    With `air` (resolution 0.5, 9840 particles, 45 us): two fields (rod and target | air) U = 1030,
    three (rod | target | air) U = 979 m/s against Tate's 1047; the air is dragged along by the rod
    (up to 2 km/s) but not compressed by it (no common pressure with the solids: when it shared it,
    the stress of the loaded metal drove the air beside it to tens of km/s within 2 us). Air in the
    solids' field (one field) is refused: it reached 25 km/s within 4 us and the run failed at 43 us.
    """
    # longer than 60 lines on purpose: a builder: its options' checks, then the bodies, materials and effects of
    # one scene
    options.check(
        "rod_penetration",
        rod_penetration_ranges(diameter),
        dict(
            resolution=resolution,
            speed=speed,
            length=length,
            diameter=diameter,
            fields=fields,
            air=air,
            drag=drag,
            target_radius=target_radius,
            target_depth=target_depth,
            t_end=t_end,
        ),
    )
    if fields == 3 and not air:
        raise ValueError("rod_penetration: fields = 3 puts air in its own field: allowed only with air = true")
    if fields == 1 and air:
        raise ValueError(
            "rod_penetration: air in the solids' velocity field is unstable (the air beside the impact "
            "reached 25 km/s within 4 us and the run failed at 43 us): allowed fields = 2 | 3 with air"
        )
    h = diameter / 10 / resolution
    target_radius = 4 * diameter if target_radius is None else target_radius
    target_depth = speed * t_end + 2 * diameter if target_depth is None else target_depth
    n_r = int(round(target_radius / h))
    n_below = int(round(target_depth / h))
    n_above = int(math.ceil(length / h)) + 3
    grid = Grid(cells=(n_r, n_below + n_above), h=h, origin=(0.0, -n_below * h))
    z_top = n_above * h
    rod_box = Box((0.0, h), (diameter / 2, h + length))
    rod_field, target_field, air_field = {1: (0, 0, 0), 2: (0, 0, 1) if air else (0, 1, 1), 3: (0, 1, 2)}[fields]
    # the air shares no common pressure with the solids (drag only): with it, the stress of the loaded
    # metal drove the air beside it to tens of km/s within 2 us
    coupled = (True if not air else False) if fields == 2 else (0, 1) if fields == 3 else True
    phases = [
        Phase("rod", "tungsten_wha", rod_box, velocity=(0.0, -speed), field=rod_field),
        Phase("target", "steel_4340", Box((0.0, -n_below * h), (n_r * h, 0.0)), field=target_field),
    ]
    if air:
        phases.append(Phase("air", "air", Difference(Box((0.0, 0.0), (n_r * h, z_top)), (rod_box,)), field=air_field))
    return Scene(
        name="rod_penetration",
        description="tungsten-alloy long rod into semi-infinite steel (2D axisymmetric)",
        grid=grid,
        axisymmetric=True,
        materials=tuple(library_material(k) for k in ("tungsten_wha", "steel_4340")),
        boundary=Boundary(faces=(("x_hi", "slip"), ("y_lo", "slip"), ("y_hi", "slip"))),
        phases=tuple(phases),
        drag=drag if fields > 1 else None,
        interface_forces=coupled,
        artificial_viscosity=(0.5, 2.0),
        t_end=t_end,
        n_out=15,
        cfl=0.3,
    )


def penetration_measures(scene: Scene, state: State) -> dict:
    """Penetration depth P (m, depth below the target's face of the deepest rod material within a
    rod radius of the axis), remaining rod length (m, from P's point to the top of the rod's tail)
    and tail speed (m/s, mean -v_z of the tail) of a rod_penetration State. The tail is the rod
    material that started within one diameter of the rod's top (eroded rod material that flows
    back up the crater is not the rod)."""
    i = scene.phase_names().index("rod")
    sl = phase_slices(scene)[i]
    x, v = np.asarray(state.x)[sl], np.asarray(state.v)[sl]
    z0 = sample_phase(scene.grid, scene.phases[i])[:, 1]
    r_rod = 0.5 * _rod_diameter(scene)
    tail = z0 > z0.max() - 2 * r_rod
    near_axis = x[:, 0] < max(r_rod, 1.5 * scene.grid.h)
    z_nose = float(x[near_axis, 1].min())
    z_top = float(x[tail, 1].max())
    return {"depth": max(-z_nose, 0.0), "rod_length": max(z_top - z_nose, 0.0), "tail_speed": float(-v[tail, 1].mean())}


def _rod_diameter(scene) -> float:
    return 2.0 * scene.phases[scene.phase_names().index("rod")].geometry.hi[0]


def penetration_history(scene: Scene, history: State) -> dict:
    """`penetration_measures` at every output time of a History: arrays t (s), depth, rod_length,
    tail_speed."""
    t = np.asarray(history.t)
    rows = [penetration_measures(scene, jax.tree.map(lambda a: a[k], history)) for k in range(len(t))]
    return {"t": t, **{key: np.array([r[key] for r in rows]) for key in rows[0]}}


def steady_penetration_rate(
    scene: Scene, history: State, window: tuple[float, float] = (0.3, 1.0)
) -> tuple[float, float]:
    """(U, U_tate) in m/s: the least-squares slope of the depth over the part `window` (fractions
    of the last output time) of the run, and the Tate speed at the tail speed averaged there."""
    m = penetration_history(scene, history)
    t = m["t"]
    keep = (t >= window[0] * t[-1]) & (t <= window[1] * t[-1])
    if keep.sum() < 3:
        raise ValueError(
            f"steady_penetration_rate: {int(keep.sum())} outputs in the window {window}: allowed >= 3 (raise n_out)"
        )
    u = float(np.polyfit(t[keep], m["depth"][keep], 1)[0])
    rho_p, rho_t = (library_constants(k)["rho0"] for k in ("tungsten_wha", "steel_4340"))
    u_tate = float(np.mean(tate_penetration_speed(m["tail_speed"][keep], rho_p, rho_t, *tate_strengths())))
    return u, u_tate


def laminate_material() -> Material:
    """The sandwich's composite layer: a CFRP laminate as a `transversely_isotropic` material whose
    symmetry axis (the model's axis 1, fibre_theta = pi / 2) is the plate's normal z, so the plies'
    plane (r, theta) is the isotropic plane and the scene stays axisymmetric. Illustrative constants
    of a quasi-isotropic carbon/epoxy laminate (the seed names no material): rho0 = 1600 kg/m^3,
    in-plane E2 = 50 GPa and nu23 = 0.3, through-thickness E1 = 10 GPa, nu12 = 0.06 (so that
    nu12 / E1 = nu21 / E2 with nu21 = 0.3), transverse shear G12 = 4 GPa."""
    return Material.make(
        "cfrp_laminate",
        "transversely_isotropic",
        rho0=1600.0,
        E1=10e9,
        E2=50e9,
        nu12=0.06,
        nu23=0.3,
        G12=4e9,
        fibre_theta=math.pi / 2,
        fibre_phi=0.0,
    )


def sandwich_target_ranges(**_: object) -> dict:
    """The allowed values of `sandwich_target`'s options (3 cells across a 3 mm face sheet, 0.5 mm / resolution each)."""
    return {
        "speed": number(0.0, unit="m/s"),
        "fields": choice(1, 2, 3),
        "drag": number(0.0),
        "t_end": number(0.0, unit="s"),
        "resolution": options.resolution(options.cells_floor(6, 3), 3, "a face sheet"),
    }


def sandwich_target(
    resolution: float = 1.0, speed: float = 800.0, fields: int = 1, drag: float = 1.0, t_end: float = 20e-6
) -> Scene:
    """A tungsten projectile into a steel / composite / steel sandwich plate (the seed's last
    example, with its anisotropic elastic model for the composite layer).

    Geometry (2D axisymmetric, r >= 0, z along the flight): a tungsten_wha rod of diameter 6 mm
    and length 18 mm, one cell above the plate, moving along -z at `speed` (800 m/s); the plate
    of radius 25 mm: steel_4340 face sheets of 3 mm on both sides of a 6 mm `laminate_material`
    core (transversely isotropic, stiff in the plies' plane, soft through the thickness), its top
    face at z = 0. Cells of 0.5 mm / resolution, 2 x 2 particles per cell; free boundaries (no
    wall takes momentum). Phases: `projectile`, `core`, `sheets` (both face sheets: one phase, one
    copy of the steel's update in the compiled step); `fields` 1 (one velocity
    field), 2 (projectile | plate, coupled by drag C_d = `drag`, the common pressure and the
    continuity form) or 3 (projectile | sheets | core).
    Effects: none (artificial viscosity needs every phase to have an equation of state, and the
    core's model has none).
    Measures: the projectile's speed and the plate's deflection against time; the plate's
    momentum and energy as it takes the impact.

    Status: runs; no measured reference (the seed shows a picture). Measured (float64, resolution
    0.5, 1416 particles, 20 us): axial momentum exact (free boundaries); one field: the rod slows
    from 800 to 615 m/s at 10 us and 295 m/s at 20 us, the back face bulges 2.6 mm, kinetic +
    internal energy drifts -0.2% (resolution 1, 5664 particles: 598 and 279 m/s, bulge 3.3 mm);
    two fields (with the continuity form, the default): 623 and 353 m/s, bulge 2.4 mm, energy -12%
    (the drag's dissipation); three fields (the core apart from the sheets): 660 and 433 m/s,
    bulge 3.6 mm, energy -4.9%. Without the continuity form (continuity = 'off') the three-field
    version gained energy fourfold in 20 us (the interface forces' work was not stored) and the
    two-field one lost 44%.
    """
    # longer than 60 lines on purpose: one scene's parameters in one place: its docstring (geometry, phases,
    # measured status), then its grid, bodies and phases; split, the geometry would be scattered
    options.check(
        "sandwich_target",
        sandwich_target_ranges(),
        dict(resolution=resolution, speed=speed, fields=fields, drag=drag, t_end=t_end),
    )
    h = 0.5e-3 / resolution
    radius, sheet, core, rod_d, rod_l = 25e-3, 3e-3, 6e-3, 6e-3, 18e-3
    below = 2 * sheet + core + speed * t_end * 0.5 + 4e-3
    n_r = int(round((radius + 2e-3) / h))
    n_below = int(math.ceil(below / h))
    n_above = int(math.ceil((rod_l + h) / h)) + 3
    grid = Grid(cells=(n_r, n_below + n_above), h=h, origin=(0.0, -n_below * h))
    f_proj, f_steel, f_core = {1: (0, 0, 0), 2: (0, 1, 1), 3: (0, 1, 2)}[fields]
    lam = laminate_material()
    core_box = Box((0.0, -sheet - core), (radius, -sheet))
    phases = (
        Phase(
            "projectile", "tungsten_wha", Box((0.0, h), (rod_d / 2, h + rod_l)), velocity=(0.0, -speed), field=f_proj
        ),
        Phase("core", lam.key, core_box, field=f_core),
        Phase(
            "sheets", "steel_4340", Difference(Box((0.0, -2 * sheet - core), (radius, 0.0)), (core_box,)), field=f_steel
        ),
    )
    return Scene(
        name="sandwich_target",
        description="tungsten rod into a steel / CFRP / steel sandwich (2D axisymmetric)",
        grid=grid,
        axisymmetric=True,
        materials=(library_material("tungsten_wha"), library_material("steel_4340"), lam),
        phases=phases,
        drag=drag if fields > 1 else None,
        t_end=t_end,
        n_out=10,
        cfl=0.3,
    )


FLUIDS = ("air", "water")


def projectile_concrete_ranges(**_: object) -> dict:
    """The allowed values of `projectile_concrete`'s options (3 cells across the projectile's 5 mm
    radius, 1 mm / resolution each)."""
    return {
        "fluid": choice(*FLUIDS),
        "speed": number(0.0, unit="m/s"),
        "drag": number(0.0),
        "standoff": number(0.0, unit="m"),
        "t_end": number(0.0, unit="s"),
        "resolution": options.resolution(options.cells_floor(5, 3), 3, "the projectile's radius"),
    }


def projectile_concrete(
    resolution: float = 1.0,
    fluid: str = "water",
    speed: float = 500.0,
    drag: float = 1.0,
    standoff: float = 10e-3,
    t_end: float = 60e-6,
) -> Scene:
    """A steel projectile through a fluid layer into a concrete block: once in air, once in water
    (the seed's two pictures of fluid-structure interaction).

    Geometry (2D axisymmetric, r >= 0, z along the flight): a steel_4340 cylinder (diameter 10 mm,
    length 30 mm, flat nose) `standoff` (10 mm) above the block's face z = 0, moving along -z at
    `speed` (500 m/s); the concrete block fills r in [0, 40 mm], z in [-60 mm, 0]; `fluid` ('air'
    at 1 atm or 'water') fills the rest of the grid above the block. Cells of 1 mm / resolution,
    2 x 2 particles per cell; slip walls on every face but the axis (they hold the fluid).
    Phases: `projectile` (steel_4340: Mie-Grueneisen, Johnson-Cook, spall, Johnson-Cook failure),
    `block` (concrete: linear EOS, Drucker-Prager strength, spall) in velocity field 0 and the
    fluid (library `air`, ideal gas, or `water`, stiffened gas) in field 1. The fluid acts on the
    solids through the exchange drag (E3, C_d = `drag`) only: the common-pressure interface forces
    are off (with them the stress of the loaded solids drove the light fluid beside them to tens of
    km/s: rod_penetration's docstring). Effects: artificial viscosity (0.5, 2.0).
    Measures (`projectile_speed`): the projectile's mean axial speed against time, and the depth
    of its nose below the block's face.

    Status: runs; the seed shows pictures, not numbers. Measured (float64, resolution 0.6, 6144
    particles, 60 us): in water the projectile reaches the block at about 450 m/s and ends at
    234 m/s, 10.8 mm deep; in air at 500 m/s, ending at 258 m/s, 12.2 mm deep. The water's drag on
    the way (500 -> 451 m/s over 10 mm) is about 6 times a flat-nosed body's Newtonian drag
    (1/2 rho v^2 C_D A with C_D = 0.8: 8.5 m/s): the exchange drag acts wherever projectile and
    water share a node, along the sides too, not only on the nose.
    """
    # longer than 60 lines on purpose: one scene's parameters in one place: its docstring (geometry, phases,
    # measured status), then its grid, bodies and phases; split, the geometry would be scattered
    options.check(
        "projectile_concrete",
        projectile_concrete_ranges(),
        dict(resolution=resolution, fluid=fluid, speed=speed, drag=drag, standoff=standoff, t_end=t_end),
    )
    h = 1e-3 / resolution
    radius, depth, p_d, p_l = 40e-3, 60e-3, 10e-3, 30e-3
    n_r = int(round(radius / h))
    n_below = int(round(depth / h))
    n_above = int(math.ceil((standoff + p_l) / h)) + 4
    grid = Grid(cells=(n_r, n_below + n_above), h=h, origin=(0.0, -n_below * h))
    proj_box = Box((0.0, standoff), (p_d / 2, standoff + p_l))
    phases = (
        Phase("projectile", "steel_4340", proj_box, velocity=(0.0, -speed), field=0),
        Phase("block", "concrete", Box((0.0, -n_below * h), (n_r * h, 0.0)), field=0),
        Phase(fluid, fluid, Difference(Box((0.0, 0.0), (n_r * h, n_above * h)), (proj_box,)), field=1),
    )
    walls = (("x_hi", "slip"), ("y_lo", "slip"), ("y_hi", "slip"))
    return Scene(
        name="projectile_concrete",
        description=f"steel projectile through {fluid} into concrete (2D axisymmetric)",
        grid=grid,
        axisymmetric=True,
        materials=tuple(library_material(k) for k in ("steel_4340", "concrete", fluid)),
        boundary=Boundary(faces=walls),
        phases=phases,
        drag=drag,
        interface_forces=False,
        artificial_viscosity=(0.5, 2.0),
        t_end=t_end,
        n_out=12,
        cfl=0.3,
    )


def projectile_speed(scene: Scene, history: State) -> dict:
    """Arrays t (s), speed (m/s, the projectile's mass-weighted mean of -v_z) and nose depth (m,
    below the block's face; negative above it) at every output of a projectile_concrete history."""
    sl = phase_slices(scene)[0]
    m, vz, z = (np.asarray(a)[:, sl] for a in (history.mass, history.v[..., 1], history.x[..., 1]))
    return {"t": np.asarray(history.t), "speed": -(m * vz).sum(1) / m.sum(1), "depth": -z.min(1)}
