"""Hypervelocity impact scenes of the seed (2D axisymmetric)."""
from __future__ import annotations

from jaxmpm.materials import library_material
from jaxmpm.scene import Box, Grid, Phase, Scene, Sphere
from jaxmpm.scenes.basic import _cells

SPHERE_DIAMETER = 9.53e-3       # m (Piekutowski 1993)
PLATE_THICKNESS = 2.21e-3       # m, t / D = 0.232
IMPACT_SPEED = 6710.0           # m/s


def debris_cloud(resolution: float = 1.0, fields: int = 1, c_h: float = 0.15, drag: float = 1.0,
                 t_end: float = 6e-6, plate_radius: float = 15e-3) -> Scene:
    """Debris cloud: an Al-2024 sphere hits a thin Al-2024 plate at 6.71 km/s (Piekutowski, Int. J.
    Impact Eng. 14 (1993) 573; the seed's "continuous to disperse flow transition" and C_h table;
    the measured feature velocities are in jaxmpm's calibration data).

    Geometry (2D axisymmetric, r >= 0, z along the flight): sphere of diameter 9.53 mm centred on
    the axis one radius plus one cell above the plate, plate 2.21 mm thick (t/D = 0.232) of radius
    `plate_radius` with its top face at z = 0. The grid spans r in [0, plate_radius + 3 mm] and
    z from 6.7 km/s * t_end + 10 mm below the plate to one sphere diameter above it, with cells of
    0.4 mm / resolution (12 cells across the sphere's radius at resolution 1).
    Phases: projectile and plate, both `al2024` from the library (Mie-Grueneisen EOS, Johnson-Cook
    strength with thermal softening, spall and Johnson-Cook failure), in `fields` velocity fields
    (2: projectile and plate apart, coupled by drag C_d = `drag` and the common pressure; 1: one
    field). Effects: the alpha closure with C_h = `c_h` (E4, E5, E8), artificial viscosity
    (0.5, 2.0). Measures: the debris cloud's shape and the axial velocities of its features.

    Status: a first version, not yet validated. Measured at resolution 1 (float32, 12 us, features
    by `jaxmpm.features` over 6-12 us): one field, C_h = 0.15: points 1, 2, 4 at 6.63, 5.48,
    4.99 km/s (experiment 6.3, 6.1, 3.9), energy -0.1%; two fields: 9.0, 5.46, 5.1 km/s with
    energy -16% (plate material jets ahead), and at resolution 0.5 the two-field run can go
    non-finite within 0.5 us. The C_h sweep and the comparison with the experiment are being built.
    """
    if fields not in (1, 2):
        raise ValueError(f"fields = {fields!r} is invalid: allowed 1 | 2")
    h = 0.4e-3 / resolution
    if not h > 0:
        raise ValueError(f"resolution = {resolution!r} is invalid: allowed > 0")
    R = SPHERE_DIAMETER / 2
    z_lo = -(PLATE_THICKNESS + IMPACT_SPEED * t_end + 10e-3)
    z_hi = 2 * R + h + SPHERE_DIAMETER
    n_r = _cells((plate_radius + 3e-3) / 0.4e-3, resolution, 4)
    n_z = _cells((z_hi - z_lo) / 0.4e-3, resolution, 4)
    al = library_material("al2024")
    return Scene(
        name="debris_cloud", description="Al-2024 sphere on an Al-2024 plate at 6.71 km/s (2D axisymmetric)",
        grid=Grid(cells=(n_r, n_z), h=h, origin=(0.0, z_lo)), axisymmetric=True, materials=(al,),
        phases=(Phase("projectile", "al2024", Sphere((0.0, R + h), R), velocity=(0.0, -IMPACT_SPEED), field=0),
                Phase("plate", "al2024", Box((0.0, -PLATE_THICKNESS), (plate_radius, 0.0)), field=fields - 1)),
        drag=drag if fields == 2 else None, c_h=c_h, artificial_viscosity=(0.5, 2.0),
        t_end=t_end, n_out=12, cfl=0.3)
