"""Hypervelocity impact scenes of the seed (2D axisymmetric): the debris cloud of a sphere through
a plate (`debris_cloud`). The Taylor impacts are in `taylor` (their names importable from here)."""

from __future__ import annotations

from jaxmpm.materials import library_material
from jaxmpm.materials.library import library_constants
from jaxmpm.model.scene import Boundary, Box, Difference, Grid, Phase, Scene, Sphere
from jaxmpm.scenes import options
from jaxmpm.scenes.basic import cells_of
from jaxmpm.scenes.options import FLAG, choice, number, optional
from jaxmpm.scenes.taylor import (  # the Taylor impacts, importable from here as well
    BRITTLE_DIAMETER as BRITTLE_DIAMETER,
    BRITTLE_LENGTH as BRITTLE_LENGTH,
    brittle_rod_material as brittle_rod_material,
    BRITTLE_SPEED as BRITTLE_SPEED,
    taylor_bar as taylor_bar,
    taylor_bar_ranges as taylor_bar_ranges,
    taylor_bilinear_copper_material as taylor_bilinear_copper_material,
    TAYLOR_BILINEAR_DIAMETER as TAYLOR_BILINEAR_DIAMETER,
    TAYLOR_BILINEAR_LENGTH as TAYLOR_BILINEAR_LENGTH,
    TAYLOR_BILINEAR_SPEED as TAYLOR_BILINEAR_SPEED,
    taylor_brittle as taylor_brittle,
    taylor_brittle_ranges as taylor_brittle_ranges,
    TAYLOR_CASES as TAYLOR_CASES,
    TAYLOR_DIAMETER as TAYLOR_DIAMETER,
    TAYLOR_LENGTH as TAYLOR_LENGTH,
    taylor_measures as taylor_measures,
    TAYLOR_SPEED as TAYLOR_SPEED,
    TAYLOR_STEEL_DIAMETER as TAYLOR_STEEL_DIAMETER,
    TAYLOR_STEEL_LENGTH as TAYLOR_STEEL_LENGTH,
    taylor_steel_material as taylor_steel_material,
    TAYLOR_STEEL_SPEED as TAYLOR_STEEL_SPEED,
)
from jaxmpm.materials import Material

SPHERE_DIAMETER = 9.53e-3  # m (Piekutowski 1993)
PLATE_THICKNESS = 2.21e-3  # m, t / D = 0.232
IMPACT_SPEED = 6710.0  # m/s


DEBRIS_CELL = 0.4e-3  # m, the cell at resolution 1
POSITIVE = number(0.0)
DEBRIS_VISCOSITY = (0.5, 2.0)  # (c_linear, c_quadratic) of the debris cloud's artificial viscosity
VISCOSITY_PAIR = options.Range(
    "[c_linear, c_quadratic], two finite numbers >= 0",
    lambda v: isinstance(v, (tuple, list)) and len(v) == 2 and all(number(0.0, strict=False).contains(x) for x in v),
)


def debris_cloud_ranges(
    plate_thickness: float = PLATE_THICKNESS, sphere_diameter: float = SPHERE_DIAMETER, **_: object
) -> dict:
    """The allowed values of `debris_cloud`'s options (the resolution's floor at the plate_thickness
    given: 4 cells across the plate; plate_radius's at the sphere_diameter given)."""
    t = plate_thickness if POSITIVE.contains(plate_thickness) else PLATE_THICKNESS
    d = sphere_diameter if POSITIVE.contains(sphere_diameter) else SPHERE_DIAMETER
    return {
        "fields": choice(1, 2),
        "c_h": POSITIVE,
        "drag": POSITIVE,
        "t_end": number(0.0, unit="s"),
        "plate_radius": number(d / 2, strict=False, unit="m", note="the sphere's radius"),
        "speed": number(0.0, unit="m/s", note="the impact speed toward the plate"),
        "plate_thickness": number(0.0, unit="m"),
        "sphere_diameter": number(0.0, unit="m"),
        "gap": optional(
            number(0.0, strict=False, unit="m", note="from the sphere to the plate's top face"), "one cell"
        ),
        "fragmentation": choice("failed", "plastic", "tensile"),
        "drag_heating": FLAG,
        "chamber_pressure": optional(number(0.0, unit="Pa", note="the chamber's air"), "vacuum"),
        "artificial_viscosity": VISCOSITY_PAIR,
        "resolution": options.resolution(options.cells_floor(t / DEBRIS_CELL, 4), 4, "the plate"),
    }


def chamber_air(pressure: float) -> Material:
    """The library's `air` (ideal gas, gamma = 1.4) at `pressure` (Pa) and the library's room
    temperature T_room: rho0 = p / (R T_room), p0 = p (1.209 kg/m^3 at 1 bar, 12.69 at 10.5 bar)."""
    c = library_constants("air")
    return library_material("air", rho0=pressure / (c["R"] * c["T_room"]), p0=pressure)


def debris_cloud_grid(
    resolution: float,
    t_end: float,
    plate_radius: float,
    speed: float,
    plate_thickness: float,
    sphere_diameter: float,
    gap: float,
) -> Grid:
    """`debris_cloud`'s grid: r in [0, plate_radius + 3 mm], z from speed * t_end + 10 mm below the
    plate's bottom face to one sphere diameter above the sphere (its centre one radius plus `gap`
    above the plate's top face, z = 0); cells of DEBRIS_CELL / resolution, at least 4 each way."""
    h = DEBRIS_CELL / resolution
    z_lo = -(plate_thickness + speed * t_end + 10e-3)
    z_hi = sphere_diameter + gap + sphere_diameter
    n_r = cells_of((plate_radius + 3e-3) / DEBRIS_CELL, resolution, 4)
    n_z = cells_of((z_hi - z_lo) / DEBRIS_CELL, resolution, 4)
    return Grid(cells=(n_r, n_z), h=h, origin=(0.0, z_lo))


def chamber_region(grid: Grid, sphere: Sphere, plate: Box, gap: float) -> Difference:
    """The chamber's air of `debris_cloud`: the grid but the sphere, the plate and the sphere's
    shadow (r < R, from the plate's top face, z = 0, up to the sphere's equator, z = R + gap)."""
    # no air in the sphere's shadow between its equator and the plate (the gap's air would be
    # trapped in the impact: squeezed to 0.5 GPa, heated to 1e6 K and jetted at 30 km/s)
    shadow = Box((0.0, 0.0), (sphere.radius, sphere.radius + gap))
    return Difference(Box(grid.origin, grid.hi), (sphere, plate, shadow))


def debris_cloud(
    resolution: float = 1.0,
    fields: int = 1,
    c_h: float = 0.15,
    drag: float = 1.0,
    t_end: float = 6e-6,
    plate_radius: float = 15e-3,
    speed: float = IMPACT_SPEED,
    plate_thickness: float = PLATE_THICKNESS,
    sphere_diameter: float = SPHERE_DIAMETER,
    gap: float | None = None,
    fragmentation: str = "failed",
    drag_heating: bool = False,
    chamber_pressure: float | None = None,
    artificial_viscosity: tuple[float, float] = DEBRIS_VISCOSITY,
) -> Scene:
    """Debris cloud: an Al-2024 sphere hits a thin Al-2024 plate at 6.71 km/s (Piekutowski, Int. J.
    Impact Eng. 14 (1993) 573; the seed's "continuous to disperse flow transition" and C_h table;
    the measured feature velocities are in jaxmpm's calibration data).

    Geometry (2D axisymmetric, r >= 0, z along the flight): sphere of diameter `sphere_diameter`
    (9.53 mm) centred on the axis one radius plus `gap` (default one cell) above the plate, plate
    `plate_thickness` (2.21 mm, t/D = 0.232) thick of radius `plate_radius` with its top face at
    z = 0; the sphere flies at `speed` (6710 m/s) along -z. At least 4 cells across the plate
    (resolution >= 0.724). The grid spans r in [0, plate_radius + 3 mm] and
    z from 6.7 km/s * t_end + 10 mm below the plate to one sphere diameter above it, with cells of
    0.4 mm / resolution (12 cells across the sphere's radius at resolution 1).
    Phases: projectile and plate, both `al2024` from the library (Mie-Grueneisen EOS, Johnson-Cook
    strength with thermal softening, spall and Johnson-Cook failure), in `fields` velocity fields
    (2: projectile and plate apart, coupled by drag C_d = `drag` and the common pressure; 1: one
    field). Effects: the alpha closure with C_h = `c_h` (E4, E5, E8; `fragmentation` 'failed': only
    failed material counts its plastic strain as fragmentation; 'plastic': the seed's E5; 'tensile':
    only plastic strain accrued in tension, compressive pressure kept, and al2024 without its failure
    parts, so that fragmentation is the closure's: docs/closure.md),
    artificial viscosity `artificial_viscosity` = (c_linear, c_quadratic), (0.5, 2.0) by default
    (docs/closure.md has the free-surface checks behind this choice); with fields = 2 and `drag_heating`, the drag's work booked as
    heat (Scene.drag_heating: the run then keeps 0.995 of its energy, 0.970 without).
    Walls: slip on the outer radius, top and bottom of the grid (jets from the contact rim reach them;
    axial momentum is kept where only the radial wall is hit). Measures: the debris cloud's shape
    and the axial velocities of its features.
    Chamber (`chamber_pressure` in Pa; None: vacuum): the chamber's air (`chamber_air`: the
    library's `air`, an ideal gas, at that pressure and the library's room temperature) fills the
    grid around the sphere and the plate, but for the sphere's shadow (r < R, from the plate up to
    the sphere's equator: the gap's air would be trapped in the impact and jetted out at tens of
    km/s; in the experiment the sphere's own bow shock has pushed it aside), in its own velocity
    field, after the solids' `fields` (fields = 1: the solids | air; 2: projectile | plate | air,
    the seed's two- and three-velocity runs). All fields share the common pressure (E6, E13, with
    the continuity form): the solids' faces carry the air's pressure, so that the air at rest stays
    at rest; and the air is coupled to the solids by the exchange drag (E3) C_d = `drag`, the seed's
    interface drag F = C_d theta_i theta_j rho_f |dv| dv / d with rho_f the air's density. The
    length d is the cell size h (Scene.drag_length None): the run resolves fragments down to about a
    cell (particles within a cell's nodes move with one nodal velocity, so a fragment smaller than a
    cell cannot leave its neighbours), and its leading debris on the axis is a layer about a cell
    thick; the drag on a fragment of size d is the seed's law for it (the test's estimate dv/dt =
    -(3/4) C_D rho_air v^2 / (rho_s d) uses the same d). `drag_heating` with the chamber books the
    drag's work between every pair of fields, also with fields = 1. The grid is the vacuum scene's:
    the bow shock stays within a few cells of the front; its wings and the back-spray reach the
    side and top walls from about 2.5 us, and the slip walls then take a little axial momentum,
    but what they reflect does not reach the cloud within the run (docs/guide/scenes.md has the
    measured fronts, the bow shock, the check in a wider grid and run times).

    Status: partly validated. Measured (one field, C_h = 0.02, float64, features over 3-6 us),
    points 1, 2, 4 in km/s against the experiment's 6.3, 6.1, 3.9 (the seed: 6.29, 5.97, 3.92):
      resolution 0.75 (1004 particles):  5.59, 5.59, 5.10
      resolution 1.0  (1718 particles):  5.96, 6.09, 4.87
      resolution 1.5  (3910 particles):  5.67, 5.62, 4.34
      resolution 2.0  (6868 particles):  5.62, 5.74, 4.10
    (with the closure's ambient pressure of the other phases, E8; CHANGELOG.md has the features
    before it.)
    The projectile's rear (point 4) converges toward the measured 3.9; the front of the debris
    (points 1 and 2) is 0.3-0.6 km/s slow. C_h barely matters with 'failed' (at resolution 1,
    C_h = 1: 5.97, 6.13, 4.87), so the seed's trend (point 4 from 3.9 to 6.1 as C_h grows) is not
    reproduced. With fragmentation = 'plastic' (the seed's literal E5) the trend is there but the
    shock dies in the plate (C_h = 0.02, without the walls, resolution 1: 5.33, 5.33, 6.10;
    resolution 2: 5.35, 5.35, 6.15): jaxmpm.stages.closure.fragmentation_gate says why.
    With fragmentation = 'tensile' (one field) C_h moves point 4 as in the seed at resolution 2:
    4.28 (C_h = 0.02), 4.98, 5.50, 6.09 (C_h = 1), points 1 and 2 at 5.4-5.9 (docs/closure.md has
    the sweeps at resolutions 0.75 to 3; the front, point 1, stays 0.4-0.6 km/s slow). With
    fields = 2 a weak drag (C_d <= 0.2 at resolution 2) passes the projectile through the plate, and
    point 1 is then projectile material: `jaxmpm.features.plate_lead` checks it.
    """
    # longer than 60 lines on purpose: most of it is the docstring (the scene, its sources and its measured
    # status); the code checks the options, then builds the bodies, the grid and the chamber in a few lines
    options.check(
        "debris_cloud",
        debris_cloud_ranges(plate_thickness, sphere_diameter),
        dict(
            resolution=resolution,
            fields=fields,
            c_h=c_h,
            drag=drag,
            t_end=t_end,
            plate_radius=plate_radius,
            speed=speed,
            plate_thickness=plate_thickness,
            sphere_diameter=sphere_diameter,
            gap=gap,
            fragmentation=fragmentation,
            drag_heating=drag_heating,
            chamber_pressure=chamber_pressure,
            artificial_viscosity=artificial_viscosity,
        ),
    )
    air = chamber_pressure is not None
    if drag_heating and fields != 2 and not air:
        raise ValueError(
            f"debris_cloud: drag_heating = {drag_heating!r} is invalid: allowed only with fields = 2 or a "
            "chamber_pressure (the heat is the drag's work between velocity fields; one field in vacuum has no drag)"
        )
    gap = DEBRIS_CELL / resolution if gap is None else gap
    R = sphere_diameter / 2
    al = (
        library_material("al2024", model="mie_gruneisen+johnson_cook_thermal")
        if fragmentation == "tensile"
        else library_material("al2024")
    )
    sphere = Sphere((0.0, R + gap), R)
    plate = Box((0.0, -plate_thickness), (plate_radius, 0.0))
    grid = debris_cloud_grid(resolution, t_end, plate_radius, speed, plate_thickness, sphere_diameter, gap)
    phases = [
        Phase("projectile", "al2024", sphere, velocity=(0.0, -speed), field=0),
        Phase("plate", "al2024", plate, field=fields - 1),
    ]
    materials = (al,)
    if air:
        gas = chamber_air(chamber_pressure)
        materials = (al, gas)
        phases.append(Phase("air", gas.key, chamber_region(grid, sphere, plate, gap), field=fields))
    return Scene(
        name="debris_cloud",
        description="Al-2024 sphere on an Al-2024 plate at 6.71 km/s (2D axisymmetric)"
        + (f" in air at {chamber_pressure:g} Pa" if air else ""),
        grid=grid,
        axisymmetric=True,
        materials=materials,
        boundary=Boundary(faces=(("x_hi", "slip"), ("y_lo", "slip"), ("y_hi", "slip"))),
        phases=tuple(phases),
        drag=drag if fields == 2 or air else None,
        drag_heating=drag_heating,
        c_h=c_h,
        fragmentation=fragmentation,
        artificial_viscosity=tuple(float(c) for c in artificial_viscosity),
        t_end=t_end,
        n_out=12,
        cfl=0.3,
    )
