"""Small built-in scenes: the default impact, verification problems, the peers' benchmark."""
from __future__ import annotations

import math

from jaxmpm.materials import Material
from jaxmpm.scene import MAX_PPC, Boundary, Box, Grid, Phase, Scene, Sphere


def _cells(n: float, resolution: float, minimum: int = 2) -> int:
    if not resolution > 0:
        raise ValueError(f"resolution = {resolution!r} is invalid: allowed > 0")
    return max(minimum, int(round(n * resolution)))


def elastic_impact(resolution: float = 1.0, shape: str = "ddmp") -> Scene:
    """Two elastic disks collide (Sulsky, Chen & Schreyer, CMAME 118 (1994) 179, the classic MPM test).

    Geometry: unit square, disks of radius 0.2 m centred at (0.25, 0.25) and (0.75, 0.75) m,
    velocities +-(0.1, 0.1) m/s; 64 x 64 cells at resolution 1, 2 x 2 particles per cell.
    Phases: both disks of a hypoelastic material (Jaumann rate, objective under the disks' large
    rotations; rho0 = 1000 kg/m^3, E = 1 kPa, nu = 0.3) in one
    velocity field (no contact algorithm: the shared field makes them stick and rebound elastically).
    Effects: none; walls free. Measures: kinetic/strain energy exchange and total energy, momentum.
    """
    n = _cells(64, resolution, 8)
    mat = Material.make("soft_elastic", "hypoelastic", rho0=1000.0, E=1000.0, nu=0.3)
    return Scene(
        name="elastic_impact", description="two elastic disks collide head-on (2D plane strain)",
        grid=Grid(cells=(n, n), h=1.0 / n), shape=shape, materials=(mat,),
        phases=(Phase("disk_a", "soft_elastic", Sphere((0.25, 0.25), 0.2), velocity=(0.1, 0.1)),
                Phase("disk_b", "soft_elastic", Sphere((0.75, 0.75), 0.2), velocity=(-0.1, -0.1))),
        t_end=3.0, n_out=30, cfl=0.3)


BAR_LENGTH, BAR_SPEED = 25.0, 10.0


def vibrating_bar_state(scene, params, state):
    """The bar's first mode: v(X, 0) = v0 sin(pi X / (2 L)), the amplitude v0 (m/s) being the
    phase's initial velocity (state.v on entry)."""
    import dataclasses

    import jax.numpy as jnp

    beta = math.pi / (2 * BAR_LENGTH)
    return dataclasses.replace(state, v=state.v * jnp.sin(beta * state.x[:, :1]))


def _fixed_low_end(cells: int, h: float, shape: str):
    """(grid, boundary) of a 1D body fixed at x = 0 on `cells` cells of size h (m). The quadratic
    B-spline's stencil spans a node on either side of a particle's cell, so with shape "bspline2"
    the grid starts one cell below x = 0 and both nodes at and below the fixed end are held."""
    if shape == "bspline2":
        return Grid(cells=(cells + 1,), h=h, origin=(-h,)), Boundary(faces=(("x_lo", "fixed"),), layers=2)
    return Grid(cells=(cells,), h=h), Boundary(faces=(("x_lo", "fixed"),))


def _check_cells(scene: str, name: str, value, least: int) -> None:
    """A builder's cell count: an integer >= least (named as the option, not as the grid it makes)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise ValueError(f"{scene}: {name} = {value!r} is invalid: allowed an integer >= {least}")


def vibrating_bar(cells: int = 100, v0: float = 0.1, shape: str = "ddmp", cfl: float = 0.1, ppc: int = 2) -> Scene:
    """1D fixed-free bar in its first mode (Bardenhagen, J. Strain Anal. 37 (2002); PHYSICS section 4).

    Bar L = 25 m, E = 100 Pa, rho = 1 kg/m^3 (c = 10 m/s), fixed at x = 0, free at x = L; the grid
    extends 20% past the free end. Initial velocity v(x, 0) = v0 sin(beta x), beta = pi / (2 L) (v0 is the phase velocity),
    set by `vibrating_bar_state` (applied by `jaxmpm.scenes.initial_state` and `jaxmpm run`). Exact: u(x, t) = (v0 / omega) sin(omega t) sin(beta x), omega = beta c.
    Measures: displacement error against the exact solution, energy conservation. With shape
    "bspline2" the grid starts one cell below x = 0 (`_fixed_low_end`).
    """
    _check_cells("vibrating_bar", "cells", cells, 2)
    L = BAR_LENGTH
    h = L / cells
    n_grid = cells + max(2, int(math.ceil(0.2 * cells)))
    mat = Material.make("bar", "linear_elastic", rho0=1.0, E=100.0, nu=0.0)
    grid, boundary = _fixed_low_end(n_grid, h, shape)
    return Scene(name="vibrating_bar", description="1D fixed-free bar, first mode",
                 grid=grid, shape=shape, materials=(mat,),
                 phases=(Phase("bar", "bar", Box((0.0,), (L,)), velocity=(v0,), ppc=ppc),),
                 boundary=boundary, cfl=cfl, t_end=10.0, n_out=10)


def self_weight_column(cells: int = 25, shape: str = "ddmp", load: float = 0.2, ppc: int = 2) -> Scene:
    """1D soft column under its own weight (Bardenhagen & Kober, CMES 5 (2004) 477 style).

    Column L = 1 m, rho = 1 kg/m^3, linear elastic with E chosen so that rho g L / E = `load`
    (particles cross several cells as it settles); fixed at x = 0, free top; gravity -10 m/s^2 ramped
    over 5 wave periods; light damping. Exact static stress in the reference position X:
    sigma(X) = -rho g (L - X) (1D, any strain, since sigma = E (F - 1) is the nominal stress).
    With shape "bspline2" the grid starts one cell below x = 0 (`_fixed_low_end`).
    """
    _check_cells("self_weight_column", "cells", cells, 2)
    if not (isinstance(load, (int, float)) and not isinstance(load, bool) and 0 < load < 1):
        raise ValueError(f"self_weight_column: load = {load!r} is invalid: allowed a number in (0, 1) (rho g L / E)")
    L, rho, g = 1.0, 1.0, 10.0
    E = rho * g * L / load
    h = L / cells
    c = math.sqrt(E / rho)
    period = 4 * L / c
    mat = Material.make("column", "linear_elastic", rho0=rho, E=E, nu=0.0)
    grid, boundary = _fixed_low_end(cells + 4, h, shape)
    return Scene(name="self_weight_column", description="1D column settling under self-weight",
                 grid=grid, shape=shape, materials=(mat,),
                 phases=(Phase("column", "column", Box((0.0,), (L,)), ppc=ppc),),
                 boundary=boundary, gravity=(-g,), gravity_ramp=5 * period,
                 damping=2.0 / period, cfl=0.2, t_end=20 * period, n_out=10)


def mpm88(n_grid: int = 128, dim: int = 2, ppc_scale: float = 1.0) -> Scene:
    """The peers' benchmark scene ('mpm88'; ../shared/bench/peers/scene.py): a weakly compressible
    fluid block (K = 400 Pa, rho = 1 kg/m^3) falling under gravity 9.8 m/s^2 in a unit box with
    slip walls 3 nodes thick, quadratic B-spline APIC (MLS) transfer. The peers sample 8192 random
    particles (2D) in [0.15, 0.55]^d; here a regular lattice of about the same count fills that box.
    """
    _check_cells("mpm88", "n_grid", n_grid, 8)
    if dim not in (2, 3):
        raise ValueError(f"mpm88: dim = {dim!r} is invalid: allowed 2 | 3")
    if not (isinstance(ppc_scale, (int, float)) and math.isfinite(ppc_scale) and ppc_scale > 0):
        raise ValueError(f"mpm88: ppc_scale = {ppc_scale!r} is invalid: allowed a finite number > 0")
    n_particles = int((8192 if dim == 2 else 8 * n_grid**dim // 32) * ppc_scale)
    box = 0.4
    cells_in_box = box * n_grid
    ppc = max(1, int(round((n_particles / cells_in_box**dim) ** (1.0 / dim))))
    if ppc > MAX_PPC:
        least = math.ceil(n_particles ** (1.0 / dim) / (box * (MAX_PPC + 0.5)))
        raise ValueError(f"mpm88: n_grid = {n_grid} with ppc_scale = {ppc_scale:g} needs {ppc} particles per cell per axis "
                         f"for the peers' {n_particles} particles: allowed at most {MAX_PPC} (n_grid >= {least} at this "
                         f"ppc_scale, or a smaller ppc_scale)")
    mat = Material.make("mpm88_fluid", "linear_fluid", rho0=1.0, K=400.0)
    walls = tuple((f"{a}_{s}", "slip") for a in "xyz"[:dim] for s in ("lo", "hi"))
    return Scene(name="mpm88", description="peers' benchmark: weakly compressible fluid, APIC",
                 grid=Grid(cells=(n_grid,) * dim, h=1.0 / n_grid), shape="bspline2", transfer="apic",
                 materials=(mat,), phases=(Phase("fluid", "mpm88_fluid", Box((0.15,) * dim, (0.55,) * dim), ppc=ppc),),
                 gravity=(0.0, -9.8) if dim == 2 else (0.0, -9.8, 0.0), boundary=Boundary(faces=walls, layers=3),
                 cfl=0.5, t_end=0.1, n_out=10)
