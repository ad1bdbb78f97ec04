"""Small built-in scenes: the default impact, verification problems, the peers' benchmark."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from jaxmpm.materials import Material
from jaxmpm.model.scene import MAX_PPC, SHAPES, Boundary, Box, Grid, Phase, Scene, Sphere
from jaxmpm.scenes import options
from jaxmpm.scenes.options import FLAG, Range, choice, integer, number  # noqa: F401  (FLAG: the builders' flags)
from jaxmpm.model.params import Params
from jaxmpm.model.state import State

SHAPE = choice(*SHAPES)
PPC = Range(
    f"an integer in [1, {MAX_PPC}]", lambda v: isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_PPC
)
CFL = Range("a number in (0, 1]", lambda v: options._real(v) and 0 < v <= 1)


def cells_of(n: float, resolution: float, minimum: int = 2) -> int:
    """round(n resolution) cells; a resolution that gives fewer than `minimum` is an error (the
    builder's resolution floor refuses it first), never silently raised to the minimum."""
    cells = int(round(n * resolution)) if resolution > 0 else 0
    if cells < minimum:
        raise ValueError(
            f"resolution = {resolution!r} gives {cells} cells: allowed >= {minimum / n:.3g} ({minimum} cells)"
        )
    return cells


IMPACT_CELLS, IMPACT_LEAST_CELLS = 64, 8  # cells across the unit square at resolution 1, at least


def elastic_impact_ranges(**_: object) -> dict:
    """The allowed values of `elastic_impact`'s options."""
    floor = options.cells_floor(IMPACT_CELLS, IMPACT_LEAST_CELLS)
    return {"resolution": options.resolution(floor, IMPACT_LEAST_CELLS, "the unit square"), "shape": SHAPE}


def elastic_impact(resolution: float = 1.0, shape: str = "ddmp") -> Scene:
    """Two elastic disks collide (Sulsky, Chen & Schreyer, CMAME 118 (1994) 179, the classic MPM test).

    Geometry: unit square, disks of radius 0.2 m centred at (0.25, 0.25) and (0.75, 0.75) m,
    velocities +-(0.1, 0.1) m/s; 64 x 64 cells at resolution 1, 2 x 2 particles per cell.
    Phases: both disks of a hypoelastic material (Jaumann rate, objective under the disks' large
    rotations; rho0 = 1000 kg/m^3, E = 1 kPa, nu = 0.3) in one
    velocity field (no contact algorithm: the shared field makes them stick and rebound elastically).
    Effects: none; walls free. Measures: kinetic/strain energy exchange and total energy, momentum.
    """
    options.check("elastic_impact", elastic_impact_ranges(), dict(resolution=resolution, shape=shape))
    n = cells_of(IMPACT_CELLS, resolution, IMPACT_LEAST_CELLS)
    mat = Material.make("soft_elastic", "hypoelastic", rho0=1000.0, E=1000.0, nu=0.3)
    return Scene(
        name="elastic_impact",
        description="two elastic disks collide head-on (2D plane strain)",
        grid=Grid(cells=(n, n), h=1.0 / n),
        shape=shape,
        materials=(mat,),
        phases=(
            Phase("disk_a", "soft_elastic", Sphere((0.25, 0.25), 0.2), velocity=(0.1, 0.1)),
            Phase("disk_b", "soft_elastic", Sphere((0.75, 0.75), 0.2), velocity=(-0.1, -0.1)),
        ),
        t_end=3.0,
        n_out=30,
        cfl=0.3,
    )


BAR_LENGTH, BAR_SPEED = 25.0, 10.0


def vibrating_bar_state(scene: Scene, params: Params, state: State) -> State:
    """The bar's first mode: v(X, 0) = v0 sin(pi X / (2 L)), the amplitude v0 (m/s) being the
    phase's initial velocity (state.v on entry)."""

    beta = math.pi / (2 * BAR_LENGTH)
    return dataclasses.replace(state, v=state.v * jnp.sin(beta * state.x[:, :1]))


def _fixed_low_end(cells: int, h: float, shape: str):
    """(grid, boundary) of a 1D body fixed at x = 0 on `cells` cells of size h (m). The quadratic
    B-spline's stencil spans a node on either side of a particle's cell, so with shape "bspline2"
    the grid starts one cell below x = 0 and both nodes at and below the fixed end are held."""
    if shape == "bspline2":
        return Grid(cells=(cells + 1,), h=h, origin=(-h,)), Boundary(faces=(("x_lo", "fixed"),), layers=2)
    return Grid(cells=(cells,), h=h), Boundary(faces=(("x_lo", "fixed"),))


def vibrating_bar_ranges(**_: object) -> dict:
    """The allowed values of `vibrating_bar`'s options."""
    return {
        "cells": integer(2),
        "v0": Range("a finite number (m/s)", options._real),
        "shape": SHAPE,
        "cfl": CFL,
        "ppc": PPC,
    }


def vibrating_bar(cells: int = 100, v0: float = 0.1, shape: str = "ddmp", cfl: float = 0.1, ppc: int = 2) -> Scene:
    """1D fixed-free bar in its first mode (Bardenhagen, J. Strain Anal. 37 (2002); PHYSICS section 4).

    Bar L = 25 m, E = 100 Pa, rho = 1 kg/m^3 (c = 10 m/s), fixed at x = 0, free at x = L; the grid
    extends 20% past the free end. Initial velocity v(x, 0) = v0 sin(beta x), beta = pi / (2 L) (v0 is the phase velocity),
    set by `vibrating_bar_state` (applied by `jaxmpm.scenes.initial_state` and `jaxmpm run`). Exact: u(x, t) = (v0 / omega) sin(omega t) sin(beta x), omega = beta c.
    Measures: displacement error against the exact solution, energy conservation. With shape
    "bspline2" the grid starts one cell below x = 0 (`_fixed_low_end`).
    """
    options.check("vibrating_bar", vibrating_bar_ranges(), dict(cells=cells, v0=v0, shape=shape, cfl=cfl, ppc=ppc))
    L = BAR_LENGTH
    h = L / cells
    n_grid = cells + max(2, int(math.ceil(0.2 * cells)))
    mat = Material.make("bar", "linear_elastic", rho0=1.0, E=100.0, nu=0.0)
    grid, boundary = _fixed_low_end(n_grid, h, shape)
    return Scene(
        name="vibrating_bar",
        description="1D fixed-free bar, first mode",
        grid=grid,
        shape=shape,
        materials=(mat,),
        phases=(Phase("bar", "bar", Box((0.0,), (L,)), velocity=(v0,), ppc=ppc),),
        boundary=boundary,
        cfl=cfl,
        t_end=10.0,
        n_out=10,
    )


def self_weight_column_ranges(**_: object) -> dict:
    """The allowed values of `self_weight_column`'s options."""
    return {
        "cells": integer(2),
        "shape": SHAPE,
        "load": Range("a number in (0, 1) (rho g L / E)", lambda v: options._real(v) and 0 < v < 1),
        "ppc": PPC,
    }


def self_weight_column(cells: int = 25, shape: str = "ddmp", load: float = 0.2, ppc: int = 2) -> Scene:
    """1D soft column under its own weight (Bardenhagen & Kober, CMES 5 (2004) 477 style).

    Column L = 1 m, rho = 1 kg/m^3, linear elastic with E chosen so that rho g L / E = `load`
    (particles cross several cells as it settles); fixed at x = 0, free top; gravity -10 m/s^2 ramped
    over 5 wave periods; light damping. Exact static stress in the reference position X:
    sigma(X) = -rho g (L - X) (1D, any strain, since sigma = E (F - 1) is the nominal stress).
    With shape "bspline2" the grid starts one cell below x = 0 (`_fixed_low_end`).
    """
    options.check("self_weight_column", self_weight_column_ranges(), dict(cells=cells, shape=shape, load=load, ppc=ppc))
    L, rho, g = 1.0, 1.0, 10.0
    E = rho * g * L / load
    h = L / cells
    c = math.sqrt(E / rho)
    period = 4 * L / c
    mat = Material.make("column", "linear_elastic", rho0=rho, E=E, nu=0.0)
    grid, boundary = _fixed_low_end(cells + 4, h, shape)
    return Scene(
        name="self_weight_column",
        description="1D column settling under self-weight",
        grid=grid,
        shape=shape,
        materials=(mat,),
        phases=(Phase("column", "column", Box((0.0,), (L,)), ppc=ppc),),
        boundary=boundary,
        gravity=(-g,),
        gravity_ramp=5 * period,
        damping=2.0 / period,
        cfl=0.2,
        t_end=20 * period,
        n_out=10,
    )


MPM88_BOX = (0.15, 0.55)  # the fluid block's lower and upper corner (m, every axis)


def mpm88_particles(n_grid: int, dim: int, ppc_scale: float) -> tuple[int, int]:
    """(particles, particles per cell per axis) of `mpm88`: the peers' 8192 particles in 2D
    (8 n_grid^3 / 32 in 3D) times ppc_scale, laid as a lattice over the block."""
    n_particles = int((8192 if dim == 2 else 8 * n_grid**dim // 32) * ppc_scale)
    cells_in_box = (MPM88_BOX[1] - MPM88_BOX[0]) * n_grid
    return n_particles, max(1, int(round((n_particles / cells_in_box**dim) ** (1.0 / dim))))


def mpm88_least_n_grid(dim: int = 2, ppc_scale: float = 1.0) -> int:
    """The smallest n_grid (>= 8) at which `mpm88`'s particles need at most MAX_PPC per cell per axis."""
    n = 8
    if dim == 2:  # the particle count is fixed: start near the bound, then step to it
        n = max(
            8, int(mpm88_particles(8, dim, ppc_scale)[0] ** 0.5 / ((MPM88_BOX[1] - MPM88_BOX[0]) * (MAX_PPC + 0.5))) - 1
        )
    while mpm88_particles(n, dim, ppc_scale)[1] > MAX_PPC and n < 100_000:  # 3D: the same ppc at any n_grid
        n += 1
    return n


def _mpm88_scale_cap(dim: int) -> float:
    """The largest ppc_scale `mpm88` takes in 3D, where the particles per cell do not depend on
    n_grid (inf in 2D, where a finer grid takes any ppc_scale)."""
    side = MPM88_BOX[1] - MPM88_BOX[0]
    return (MAX_PPC + 0.5) ** 3 * side**3 * 32 / 8 if dim == 3 else math.inf


def mpm88_ranges(dim: int = 2, ppc_scale: float = 1.0, **_: object) -> dict:
    """The allowed values of `mpm88`'s options; n_grid's floor at the dim and ppc_scale given."""
    ok = dim in (2, 3) and options._real(ppc_scale) and ppc_scale > 0
    least = mpm88_least_n_grid(dim, ppc_scale) if ok else 8
    note = f"at dim = {dim}, ppc_scale = {ppc_scale:g}: at most {MAX_PPC} particles per cell per axis" if ok else ""
    cap = _mpm88_scale_cap(dim)
    scale = (
        number(0.0)
        if cap == math.inf
        else Range(
            f"a finite number in (0, {cap:.4g}) (at dim = 3 the particles per cell do not depend on n_grid: at most "
            f"{MAX_PPC} per axis)",
            lambda v: options._real(v) and 0 < v < cap,
        )
    )
    return {"n_grid": integer(least, note), "dim": choice(2, 3), "ppc_scale": scale}


def mpm88(n_grid: int = 128, dim: int = 2, ppc_scale: float = 1.0) -> Scene:
    """The peers' benchmark scene ('mpm88'; ../shared/bench/peers/scene.py): a weakly compressible
    fluid block (K = 400 Pa, rho = 1 kg/m^3) falling under gravity 9.8 m/s^2 in a unit box with
    walls 3 nodes thick that, like the peers', hold only the velocity into them ('separating'),
    quadratic B-spline APIC (MLS) transfer. The peers sample 8192 random
    particles (2D) in [0.15, 0.55]^d; here a regular lattice of about the same count fills that box.
    """
    options.check("mpm88", {"dim": choice(2, 3)}, dict(dim=dim))
    options.check("mpm88", mpm88_ranges(dim), dict(ppc_scale=ppc_scale))
    options.check("mpm88", mpm88_ranges(dim, ppc_scale), dict(n_grid=n_grid))
    n_particles, ppc = mpm88_particles(n_grid, dim, ppc_scale)
    mat = Material.make("mpm88_fluid", "linear_fluid", rho0=1.0, K=400.0)
    walls = tuple((f"{a}_{s}", "separating") for a in "xyz"[:dim] for s in ("lo", "hi"))
    return Scene(
        name="mpm88",
        description="peers' benchmark: weakly compressible fluid, APIC",
        grid=Grid(cells=(n_grid,) * dim, h=1.0 / n_grid),
        shape="bspline2",
        transfer="apic",
        materials=(mat,),
        phases=(Phase("fluid", "mpm88_fluid", Box((MPM88_BOX[0],) * dim, (MPM88_BOX[1],) * dim), ppc=ppc),),
        gravity=(0.0, -9.8) if dim == 2 else (0.0, -9.8, 0.0),
        boundary=Boundary(faces=walls, layers=3),
        cfl=0.5,
        t_end=0.1,
        n_out=10,
    )
