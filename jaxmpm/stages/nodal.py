"""Nodal quantities from the particles, shared by the step's stages: named scatters, the stress
force parts (E11), the particle radius of axisymmetric scenes, the DDMP grid operators (R1-R3)
and the nodes' support volumes.

Shapes: N particles, S stencil nodes, K velocity fields, d dimensions; `layout` is a
jaxmpm.stages.layout.Layout. SI units.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.typing import DTypeLike

from jaxmpm.model.state import State
from jaxmpm.numerics import ddmp
from jaxmpm.numerics.shapes import Stencil
from jaxmpm.numerics.transfer import cell_sum, scatter, stencil_apply
from jaxmpm.stages.layout import Layout


def grid_shape(layout: Layout) -> tuple[int, ...]:
    """(K, *nodes): the nodal array shape of a Layout's fields."""
    return (layout.n_fields,) + tuple(layout.scene.grid.nodes)


class NodalSums(NamedTuple):
    """What the particle-to-grid stage (2) scatters onto the grid and the later stages read: the sums
    over particles p of each field (or, by phase, each phase) K at each node n of the stencil weights
    S_np times what the particle carries. d dimensions, C a fit's moments. None where the scene has
    no use for it."""

    mass: jax.Array | None = None  # (K, n, 1) kg: sum m_p S_np
    momentum: jax.Array | None = None  # (K, n, d) kg m/s: sum m_p v_p S_np
    force: jax.Array | None = None  # (K, n, d) N: the particles' stress force, -V beta sigma . grad S (E11)
    stress_share: jax.Array | None = None  # (K, n, d*d) N m: DDMP's nodal share V (1 - beta) sigma S (E11)
    pressure_share: jax.Array | None = None  # (K, n, 1) N m: the same of an isotropic pressure (E13)
    volume: jax.Array | None = None  # (K, n, 1) m^3: sum V_p S_np
    pressure_moments: jax.Array | None = None  # (K, n, C): the moments of the nodal phase pressure (E15)
    compressible_volume: jax.Array | None = None  # (K, n, 1) m^3/Pa: sum V_p kappa_p S_np

    def __getitem__(self, key):
        """A field by name, as the dict of the versions before (g.volume, g.force: the old keys
        m, mv, f, shv, shp, vol, pm, kvol name the fields mass, momentum, ...), or by position."""
        if isinstance(key, str):
            return getattr(self, OLD_KEYS.get(key, key))
        return tuple.__getitem__(self, key)

    def __contains__(self, key) -> bool:
        """Whether a field (named as by `[]`) is set: `g.volume is not None` as with the dict before."""
        if isinstance(key, str):
            return getattr(self, OLD_KEYS.get(key, key), None) is not None
        return tuple.__contains__(self, key)


# the keys of the dict the particle-to-grid scatter gave before NodalSums
OLD_KEYS = {
    "m": "mass",
    "mv": "momentum",
    "f": "force",
    "shv": "stress_share",
    "shp": "pressure_share",
    "vol": "volume",
    "pm": "pressure_moments",
    "kvol": "compressible_volume",
}


def scatter_named(layout: Layout, stencils: Stencil, parts: dict[str, jax.Array], by_phase: bool = False) -> NodalSums:
    """One scatter of several contributions {NodalSums field: (N, S, C)} -> NodalSums of (K, n_nodes, C),
    K the velocity fields; by_phase: onto one grid per phase instead (K the phases). The channels are
    scattered in the order of `parts`."""
    names = list(parts)
    sizes = [parts[k].shape[-1] for k in names]
    index, count = (layout.phase, layout.n_phases) if by_phase else (layout.field, layout.n_fields)
    sums = layout.particle_sum(
        scatter(stencils, index, jnp.concatenate([parts[k] for k in names], -1), count, layout.n_nodes)
    )
    out, i = {}, 0
    for k, c in zip(names, sizes):
        out[k] = sums[..., i : i + c]
        i += c
    return NodalSums(**out)


def stress_parts(
    stencils: Stencil, volume: jax.Array, beta: jax.Array | None, sig: jax.Array, radius: jax.Array | None = None
) -> dict[str, jax.Array]:
    """Force contributions of particle stresses sig (N, d, d): the particle part
    -V beta sig . grad S (E11; beta = 1 without DDMP) and DDMP's nodal share V (1 - beta) sig S.
    Axisymmetric (radius (N,) given, sig (N, 3, 3) with theta last): the (r, z) block as above plus
    the hoop force -V sig_thth S / r along r (PHYSICS 2.3), adjoint to L_thth = v_r / r."""
    if radius is not None:
        hoop = -(volume * sig[:, 2, 2] / radius)[:, None] * stencils.w
        sig = sig[:, :2, :2]
    d = sig.shape[-1]
    Vb = volume if beta is None else volume * beta
    parts = {"force": -stencil_apply(Vb[:, None, None] * sig, stencils.dw)}
    if radius is not None:
        parts["force"] = parts["force"].at[..., 0].add(hoop)
    if beta is not None:
        shv = ((volume * (1 - beta))[:, None, None] * sig).reshape(-1, d * d)
        parts["stress_share"] = stencils.w[..., None] * shv[:, None, :]
    return parts


def pressure_parts(
    stencils: Stencil, volume: jax.Array, beta: jax.Array | None, p: jax.Array, radius: jax.Array | None = None
) -> dict[str, jax.Array]:
    """`stress_parts` of the isotropic stress p I (p: (N,) Pa), with DDMP's nodal share as one
    channel `pressure_share` = V (1 - beta) p S instead of the d^2 of `stress_share` (its tensor is p_hat I): the
    same forces from a narrower scatter (the interface forces, E13; `ddmp.nodal_interface_force`
    contracts the share)."""
    Vb = volume if beta is None else volume * beta
    f = -(Vb * p)[:, None, None] * stencils.dw
    if radius is not None:
        f = f.at[..., 0].add(-(volume * p / radius)[:, None] * stencils.w)
    parts = {"force": f}
    if beta is not None:
        parts["pressure_share"] = stencils.w[..., None] * (volume * (1 - beta) * p)[:, None, None]
    return parts


def particle_radius(layout: Layout, state: State) -> jax.Array | None:
    """(N,) particle radius r (m) in axisymmetric scenes, else None."""
    return state.x[:, 0] if layout.scene.axisymmetric else None


def nodal_stress_force(layout: Layout, operators: ddmp.DDMPGrid | None, sums: NodalSums) -> jax.Array:
    """Nodal force (K, n_nodes, d) from the scattered stress parts (adds DDMP's E11 second part)."""
    f = sums.force
    grid = layout.scene.grid
    if sums.stress_share is not None:
        return f + ddmp.nodal_stress_force(
            grid, operators, sums.stress_share.reshape(grid_shape(layout) + (layout.dim, layout.dim))
        ).reshape(f.shape)
    return f


def ddmp_operators(
    layout: Layout, stencils: Stencil, nodal_volume: jax.Array, dtype: DTypeLike, volume: jax.Array
) -> ddmp.DDMPGrid:
    """DDMP grid operators (R1-R3) per field from the nodal particle volume (K, n_nodes) and the
    particle volumes (N,) at stencil stencils; on each field's block of scene.window cells if set."""
    scene = layout.scene
    cells = layout.particle_sum(
        cell_sum(stencils, layout.field, layout.n_fields, math.prod(scene.grid.cells), volume.astype(dtype))
    )
    return ddmp.build(
        scene.grid,
        nodal_volume.reshape(grid_shape(layout)),
        cells.reshape((layout.n_fields,) + scene.grid.cells),
        scene.axisymmetric,
        scene.window,
    )


def node_volume(layout: Layout, dtype: DTypeLike) -> jax.Array:
    """(n_nodes,) the volume of each node's support, m^d (per radian if axisymmetric)."""
    return jnp.asarray(ddmp.node_support(layout.scene.grid, layout.scene.axisymmetric).reshape(-1), dtype)


class GridUpdate(NamedTuple):
    """What the grid stage (3) hands to the grid-to-particle stage (4). K velocity fields, n nodes,
    d dimensions, N particles, P pairs of fields."""

    v: jax.Array  # (K, n, d) nodal velocity before the update (walls applied), m/s
    a: jax.Array  # (K, n, d) nodal acceleration (walls applied), m/s^2
    ddmp: object  # the DDMP operators (`ddmp_operators`), or None without DDMP or interface forces
    ambient_pressure: jax.Array | None  # (K, n) the closure's ambient pressure per field (E8), Pa, or None
    volume_rate: object  # v (K, n, d) -> (N,) 1/s, the continuity form's volume rate (E7), or None
    impulses: jax.Array | None  # (P, n, d) the exchange's pair impulses with drag_heating, N s, or None
