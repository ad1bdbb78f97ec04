"""Layout: the static facts of a scene that the traced stages use (numpy / Python only), built
once per step function by `Layout.of(scene)`; and the walls' velocity mask it holds."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.model.scene import Scene
from jaxmpm.model.state import phase_slices


@dataclass(frozen=True)
class Layout:
    """Static facts of a scene that the traced step uses (numpy / Python only)."""

    scene: object
    dim: int
    n_fields: int
    n_nodes: int
    field: np.ndarray | None  # (N,) field index per particle, None with one field
    slices: tuple  # per phase
    bc_mask: np.ndarray | None  # (n_nodes, d) 1 where a velocity component is free, None if no walls
    axis_name: str | None = None  # the mesh axis the particles are split along (jaxmpm.distributed), or None
    phase: np.ndarray | None = None  # (N,) phase index per particle, None with one phase

    @property
    def n_phases(self) -> int:
        return len(self.scene.phases)

    @property
    def ambient_by_field(self) -> bool:
        """Whether the closure's ambient pressure (E8, the common pressure of the OTHER phases)
        can be formed per velocity field from the interface forces' nodal quantities: every field
        holds one phase and the scene scatters those quantities. Otherwise it is formed per phase
        from a scatter of its own (`multifield.ambient_pressure_by_phase`)."""
        fields_of = [p.field for p in self.scene.phases]
        return self.scene.has_interface_forces and len(set(fields_of)) == len(fields_of)

    @staticmethod
    def of(scene: Scene, shards: int = 1, axis_name: str | None = None) -> "Layout":
        """The Layout of `scene`; with shards > 1, of one of `shards` equal parts of every phase's
        particles (ceil(n / shards) of a phase of n: the per-device block of `jaxmpm.distributed`),
        whose sums and maxima over particles are completed across the mesh axis `axis_name`."""
        K = scene.n_fields
        local = [-(-(sl.stop - sl.start) // shards) for sl in phase_slices(scene)]
        starts = np.concatenate([[0], np.cumsum(local)]).astype(int)
        slices = tuple(slice(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:]))
        field = np.concatenate([np.full(c, p.field, np.int32) for p, c in zip(scene.phases, local)]) if K > 1 else None
        phase = (
            np.concatenate([np.full(c, i, np.int32) for i, c in enumerate(local)]) if len(scene.phases) > 1 else None
        )
        return Layout(
            scene=scene,
            dim=scene.dim,
            n_fields=K,
            n_nodes=scene.grid.n_nodes,
            field=field,
            slices=slices,
            bc_mask=boundary_mask(scene),
            axis_name=axis_name,
            phase=phase,
        )

    def particle_sum(self, x: jax.Array) -> jax.Array:
        """A sum over particles completed across the devices: x is a scatter's nodal result
        (K, n_nodes, C) or (K, n_cells) from this device's particles; the same shape back."""
        return x if self.axis_name is None else jax.lax.psum(x, self.axis_name)

    def particle_max(self, x: jax.Array) -> jax.Array:
        """The maximum over particles of x (N,) or (N, ...), across the devices too: a scalar in
        x's units (here m/s for the CFL speeds, kg for the mass floor)."""
        m = jnp.max(x)
        if self.axis_name is None:
            return m
        # pmax has no derivative: the value by pmax, the derivative that of the devices holding it
        top = jax.lax.pmax(jax.lax.stop_gradient(m), self.axis_name)
        here = m == top
        return top + (
            jax.lax.psum(jnp.where(here, m - jax.lax.stop_gradient(m), 0.0), self.axis_name)
            / jax.lax.psum(here.astype(m.dtype), self.axis_name)
        )


def boundary_mask(scene: Scene) -> np.ndarray | None:
    """(n_nodes, d) multiplier: 0 for components a wall holds (fixed: all; slip: normal), else 1;
    None where no component is held ('separating' faces hold no component both ways:
    `separating_sides`)."""
    grid, b = scene.grid, scene.boundary
    on_axis = scene.axisymmetric and grid.origin[0] == 0.0
    if all(b.kind(k, s) in ("free", "separating") for k in range(grid.dim) for s in ("lo", "hi")) and not on_axis:
        return None
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in grid.nodes], indexing="ij"), -1).reshape(-1, grid.dim)
    mask = np.ones((grid.n_nodes, grid.dim))
    for k in range(grid.dim):
        for side in ("lo", "hi"):
            kind = b.kind(k, side)
            if kind in ("free", "separating"):
                continue
            near = wall_nodes(scene, idx, k, side)
            if kind == "fixed":
                mask[near, :] = 0.0
            else:
                mask[near, k] = 0.0
    if on_axis:  # axis condition v_r = 0 at r = 0 (PHYSICS 2.3)
        mask[idx[:, 0] == 0, 0] = 0.0
    return mask


def wall_nodes(scene: Scene, idx: np.ndarray, k: int, side: str) -> np.ndarray:
    """(n_nodes,) bool: the nodes (integer indices idx (n_nodes, d)) in the `layers` node layers
    of the face (axis k, side 'lo' or 'hi')."""
    layers, cells = scene.boundary.layers, scene.grid.cells[k]
    return idx[:, k] < layers if side == "lo" else idx[:, k] > cells - layers


@functools.lru_cache(maxsize=16)
def separating_sides(scene: Scene) -> tuple[np.ndarray, np.ndarray] | None:
    """(lo, hi), each (n_nodes, d) bool: the velocity components a 'separating' face holds from
    below (lo: the component may not be negative) and from above (hi: not positive); None where
    no face is 'separating'."""
    grid, b = scene.grid, scene.boundary
    if all(b.kind(k, s) != "separating" for k in range(grid.dim) for s in ("lo", "hi")):
        return None
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in grid.nodes], indexing="ij"), -1).reshape(-1, grid.dim)
    held = {s: np.zeros((grid.n_nodes, grid.dim), bool) for s in ("lo", "hi")}
    for k in range(grid.dim):
        for side in ("lo", "hi"):
            if b.kind(k, side) == "separating":
                held[side][wall_nodes(scene, idx, k, side), k] = True
    return held["lo"], held["hi"]


def apply_walls(layout: Layout, v: jax.Array) -> jax.Array:
    """Nodal velocities v (K, n_nodes, d) with the walls' components zeroed (`Layout.bc_mask`)
    and, at 'separating' faces, the normal component into the wall zeroed; v itself where the
    scene has no walls. Also for accelerations where no face is 'separating' (else
    `wall_acceleration`)."""
    v = v if layout.bc_mask is None else v * jnp.asarray(layout.bc_mask, v.dtype)
    sides = separating_sides(layout.scene)
    if sides is None:
        return v
    lo, hi = (jnp.asarray(s) for s in sides)
    return jnp.where(lo, jnp.maximum(v, 0), jnp.where(hi, jnp.minimum(v, 0), v))


def wall_acceleration(layout: Layout, v: jax.Array, a: jax.Array, dt: jax.Array) -> jax.Array:
    """The nodal acceleration a (K, n_nodes, d) m/s^2 the walls allow to nodes of velocity v
    (walls applied, m/s) over the step dt (s): `apply_walls` of a; at 'separating' faces, the
    acceleration that takes v to `apply_walls` of v + dt a (a node leaving the wall keeps its
    acceleration until it would move into it)."""
    sides = separating_sides(layout.scene)
    if sides is None:
        return apply_walls(layout, a)
    a = a if layout.bc_mask is None else a * jnp.asarray(layout.bc_mask, a.dtype)
    held = (apply_walls(layout, v + dt * a) - v) / jnp.where(dt > 0, dt, 1)
    return jnp.where(jnp.asarray(sides[0] | sides[1]) & (dt > 0), held, a)


# ------------------------------------------------------------------------------- stage names
# Each stage of the step runs under a jax.named_scope of its name in STAGES, and the parts of the
# grid update and of the grid-to-particle stage under those in STAGE_PARTS (where the scene has
# them): XLA's operations carry the names in their metadata, so that a profile can put its
# kernels' times on the stages (benchmarks/profile_step.py). The names change no computation.
STAGES = ("1_shape_functions", "2_particle_to_grid", "3_grid_update", "4_grid_to_particle", "5_constitutive")
STAGE_PARTS = ("ddmp_operators", "stress_force", "interface_force", "exchange", "remap", "velocity_gradient")


def mass_floor(layout: Layout, state: Any) -> jax.Array:
    """The nodal mass below which a node counts as empty, kg: eps^2 times the largest particle mass."""
    eps = jnp.finfo(state.mass.dtype).eps
    return layout.particle_max(state.mass) * eps**2
