"""The memory a scene needs, checked before anything is allocated: the grid, a phase's particle
lattice while it is sampled, and a host-driven run's history. A refusal is certain, not a guess:
each count is a lower bound of what the computation holds."""

from __future__ import annotations

import math


from jaxmpm.model.geometry import Grid
from jaxmpm.model.parts import Phase
from jaxmpm.model.sampling import lattice_cells
from jaxmpm.model.scene_fields import SceneFields


NUMBERS_PER_NODE = 16  # a lower bound: a step holds far more per node and velocity field than this


def available_memory() -> int | None:
    """Bytes of memory available to new allocations (Linux /proc/meminfo), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def lattice_points(grid: Grid, phase: Phase) -> int:
    """The number of lattice points `state.sample_phase` lays over the phase's bounding box (ppc^d per
    cell of the grid that the box touches), before it keeps those inside the geometry."""
    c_lo, c_hi = lattice_cells(grid, phase)
    return math.prod(max(int(b - a), 0) * phase.ppc for a, b in zip(c_lo, c_hi))


def check_scene_memory(scene: SceneFields, itemsize: int = 8) -> None:
    """ValueError before particles are sampled where the grid (as `check_memory`) or a phase's
    particle lattice cannot fit in the memory available: the lattice's positions alone, d numbers
    per point, are less than sampling holds, so a refusal is certain, not a guess."""
    avail = available_memory()
    if avail is None:
        return
    nodes = math.prod(c + 1 for c in scene.grid.cells)
    need = nodes * scene.n_fields * NUMBERS_PER_NODE * itemsize
    if need > avail:
        raise ValueError(
            f"grid.cells = {list(scene.grid.cells)} is invalid: its {nodes:,} nodes x {scene.n_fields} velocity "
            f"field(s) need more than {need / 2**30:.1f} GiB of memory and {avail / 2**30:.1f} GiB are "
            "available (allowed a smaller grid: fewer cells, or a larger h with --opt resolution / grid.h)"
        )
    for phase in scene.phases:
        points = lattice_points(scene.grid, phase)
        need = points * scene.dim * 8  # sampled in float64 on the host
        if need > avail:
            raise ValueError(
                f"phase.{phase.name}.ppc = {phase.ppc} is invalid with grid.h = {scene.grid.h:g} m: sampling "
                f"lays {points:,} particle positions over the phase's bounding box, more than "
                f"{need / 2**30:.1f} GiB of memory where {avail / 2**30:.1f} GiB are available (allowed fewer "
                "particles: a smaller ppc, or a larger h with --opt resolution / grid.h)"
            )


def size_text(n: float) -> str:
    """A byte count n as text in B, KiB, MiB or GiB (3 significant digits)."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{int(n)} B"


def particle_numbers(scene: SceneFields) -> int:
    """Numbers a State holds per particle at least: position and velocity (d each), mass, volume,
    energy, deformation gradient and stress (d^2 each, 3^2 axisymmetric)."""
    d = scene.dim
    tensor = 9 if scene.axisymmetric else d * d
    return 2 * d + 3 + 2 * tensor


def run_memory(
    scene: SceneFields, particles: int, n_out: int, itemsize: int, state_bytes: int | None = None
) -> tuple[int, int, int]:
    """(total, per state, grid) bytes a host-driven run needs at least: the n_out + 1 states of its
    history and the one it advances (`particle_numbers` per particle, or `state_bytes` each), and
    the grid at NUMBERS_PER_NODE numbers per node and velocity field."""
    per_state = particles * particle_numbers(scene) * itemsize if state_bytes is None else int(state_bytes)
    grid = math.prod(c + 1 for c in scene.grid.cells) * scene.n_fields * NUMBERS_PER_NODE * itemsize
    return (int(n_out) + 2) * per_state + grid, per_state, grid


def check_run_memory(
    scene: SceneFields, particles: int, n_out: int, itemsize: int, state_bytes: int | None = None
) -> None:
    """ValueError before a run (before its state is made, where `state_bytes` is None) whose history
    and grid (`run_memory`) need more memory than is available."""
    avail = available_memory()
    total, per_state, grid = run_memory(scene, particles, n_out, itemsize, state_bytes)
    if avail is not None and total > avail:
        raise ValueError(
            f"n_out = {n_out} with {particles:,} particles and grid.cells = {list(scene.grid.cells)} is "
            f"invalid here: the run keeps {int(n_out) + 1} states of {size_text(per_state)} and a grid of at least "
            f"{size_text(grid)}, {size_text(total)} in all, more than the {size_text(avail)} of memory available (allowed "
            "fewer outputs, or fewer particles: a larger h with --opt resolution / grid.h)"
        )
