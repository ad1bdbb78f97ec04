"""The checks of a Scene's fields, run in order when it is built (`Scene.__post_init__`): each
raises the project's ValueError naming the field, its value and what is allowed
(jaxmpm.model.geometry.fail), and stores the normalised value (tuples, floats) on the frozen
scene; each relies on those before it. The effects' numbers are checked from the table of
jaxmpm.model.numbers.
"""

from __future__ import annotations

from collections.abc import Iterable

from jaxmpm.materials import Material, resolve_material
from jaxmpm.materials.models import model_of
from jaxmpm.model.geometry import Grid, as_float, fail, is_integer
from jaxmpm.model.numbers import NUMBERS
from jaxmpm.model.parts import (
    AXES,
    CONTINUITY,
    ENERGY_UPDATES,
    FACE_NAMES,
    FRAGMENTATION,
    SHAPES,
    TRANSFERS,
    Boundary,
    Phase,
    is_fluid,
)
from jaxmpm.model.scene_fields import SceneFields


def check_scene_fields(scene: SceneFields) -> None:
    """Every check below, in order."""
    check_parts(scene)
    check_phases(scene)
    check_materials(scene)
    check_scheme(scene)
    check_numbers(scene)
    check_viscous_models(scene)
    check_density_diffusion(scene)
    check_axisymmetric(scene)
    check_window_shape(scene)
    check_couplings(scene)
    check_boundary(scene)
    check_run(scene)
    check_drag_heating(scene)
    check_window_use(scene)


def check_parts(scene: SceneFields) -> None:
    """The grid, the phases and materials (tuples of Phase and Material), name and description."""
    if not isinstance(scene.grid, Grid):
        fail("grid", scene.grid, "a Grid")
    for name, kind in (("phases", Phase), ("materials", Material)):
        items = getattr(scene, name)
        if (
            isinstance(items, (str, bytes, Phase, Material))
            or not isinstance(items, Iterable)
            or not all(isinstance(x, kind) for x in items)
        ):
            fail(name, items, f"a tuple of {kind.__name__}")
    for name in ("name", "description"):
        if not isinstance(getattr(scene, name), str):
            fail(name, getattr(scene, name), "a string")
    if not tuple(scene.phases):
        fail("phase", tuple(scene.phases), "at least one [[phase]]")
    object.__setattr__(scene, "phases", tuple(scene.phases))
    object.__setattr__(scene, "materials", tuple(scene.materials))


def check_phases(scene: SceneFields) -> None:
    """Unique phase names, each body inside the grid, velocity fields numbered without gaps."""
    dim = scene.grid.dim
    names = [p.name for p in scene.phases]
    for n in names:
        if names.count(n) > 1:
            fail("phase.name", n, "unique names (two phases share it)")
    for p in scene.phases:
        if len(p.geometry.lo) != dim:
            fail(f"phase.{p.name}.geometry", p.geometry.to_dict(), f"{dim} coordinates per point (grid is {dim}D)")
        for d in range(dim):
            lo, hi = scene.grid.origin[d], scene.grid.hi[d]
            if d == 0 and scene.axisymmetric is True and lo == 0.0:
                lo = -hi  # a body on the axis may be given whole (a sphere centred at r = 0)
            # a slip wall is a mirror plane: a body cut by it is given whole, its part inside is sampled
            if scene.boundary.kind(d, "lo") == "slip":
                lo = min(lo, 2 * scene.grid.origin[d] - hi)
            if scene.boundary.kind(d, "hi") == "slip":
                hi = 2 * hi - scene.grid.origin[d]
            if p.geometry.lo[d] < lo - 1e-12 * abs(hi - lo) or p.geometry.hi[d] > hi + 1e-12 * abs(hi - lo):
                fail(
                    f"phase.{p.name}.geometry",
                    p.geometry.to_dict(),
                    f"inside the grid: axis {AXES[d]} in [{lo}, {hi}] m (a particle would lie outside the grid)",
                )
    fields = sorted({p.field for p in scene.phases})
    if fields != list(range(len(fields))):
        bad = [p for p in scene.phases if p.field >= len(fields)][0]
        fail(f"phase.{bad.name}.field", bad.field, f"fields numbered 0..{len(fields) - 1} without gaps")


def check_materials(scene: SceneFields) -> None:
    """Unique material keys; every phase's material resolves (an unknown key fails here, listing
    the known ones), one material per key (a scene file names a material by its key alone)."""
    keys = [m.key for m in scene.materials]
    for k in keys:
        if keys.count(k) > 1:
            fail("materials", k, "unique material keys")
    by_key = {m.key: ("materials", m) for m in scene.materials}
    for p in scene.phases:
        m = resolve_material(p.material, scene.materials, f"phase.{p.name}.material")
        where, other = by_key.setdefault(m.key, (f"phase.{p.name}", m))
        if other != m:
            fail(
                f"phase.{p.name}.material",
                m.key,
                f"one material per key: {where} has another material of key {m.key!r} (rename one)",
            )


def check_scheme(scene: SceneFields) -> None:
    """The shape function, the transfer scheme and the energy update, that 'apic' has B-splines and
    that the 'compatible' energy update has 'musl'."""
    if scene.shape not in SHAPES:
        fail("shape", scene.shape, " | ".join(SHAPES))
    if scene.transfer not in TRANSFERS:
        fail("transfer", scene.transfer, " | ".join(TRANSFERS))
    if scene.transfer == "apic" and scene.shape != "bspline2":
        fail("transfer", scene.transfer, "'apic' only with shape = 'bspline2'")
    if scene.energy_update not in ENERGY_UPDATES:
        fail("energy_update", scene.energy_update, " | ".join(ENERGY_UPDATES))
    if scene.energy_update == "compatible" and scene.transfer != "musl":
        fail(
            "energy_update", scene.energy_update, f"'compatible' only with transfer = 'musl' (here {scene.transfer!r})"
        )


def check_numbers(scene: SceneFields) -> None:
    """The effects' numbers and cfl, from the table of jaxmpm.model.numbers: each in its range,
    and those that only act with another effect (gravity_ramp, drag_length) only with it."""
    for n in NUMBERS:
        value = getattr(scene, n.name)
        if value is not None:
            object.__setattr__(scene, n.name, n.check_scene_value(value, scene.grid.dim))
    for n in NUMBERS:
        value, switch = getattr(scene, n.name), n.switch_attribute
        if switch and switch != n.name and value not in (None, n.default) and getattr(scene, switch) is None:
            fail(n.key, value, f"only with effects.{switch} ({n.role})")
    if not isinstance(scene.body_force, bool):
        fail("effects.body_force", scene.body_force, "true | false")


def check_viscous_models(scene: SceneFields) -> None:
    """An artificial viscosity given for every phase only where each has an equation of state
    (or is a linear_fluid, which recomputes its stress from F each step: a q does not accumulate)."""
    if scene.artificial_viscosity is None:
        return
    for p in scene.phases:
        m = scene.material(p)
        if not (model_of(m.model).hydro or is_fluid(m.model)):
            fail(
                "effects.artificial_viscosity",
                list(scene.artificial_viscosity),
                f"only with equation-of-state models and linear_fluid: phase {p.name!r} uses {m.model!r}",
            )


def check_density_diffusion(scene: SceneFields) -> None:
    """The fluids' density diffusion delta in [0, 1] (dimensionless; 0: off)."""
    delta = as_float("effects.density_diffusion", scene.density_diffusion)
    if not 0 <= delta <= 1:
        fail("effects.density_diffusion", delta, "[0, 1] (dimensionless; 0: off)")
    object.__setattr__(scene, "density_diffusion", delta)


def check_axisymmetric(scene: SceneFields) -> None:
    """Axisymmetric: a 2D (r, z) grid at r >= 0, with the shapes and updates that have a hoop term."""
    if not isinstance(scene.axisymmetric, bool):
        fail("axisymmetric", scene.axisymmetric, "true | false")
    if not scene.axisymmetric:
        return
    if scene.dim != 2:
        fail("axisymmetric", True, f"only with a 2D (r, z) grid (grid is {scene.dim}D)")
    if scene.grid.origin[0] < 0:
        fail("grid.origin[0]", scene.grid.origin[0], ">= 0 m (the radius of an axisymmetric grid)")
    if scene.shape == "bspline2" or scene.transfer == "apic":
        fail("axisymmetric", True, "only with shape 'ddmp' or 'linear' and the musl / seed updates")


def check_window_shape(scene: SceneFields) -> None:
    """A window is d cell counts, each within the grid's."""
    if scene.window is None:
        return
    w, dim = scene.window, scene.dim
    ok = (
        isinstance(w, (tuple, list))
        and len(w) == dim
        and all(is_integer(c) and 1 <= c <= n for c, n in zip(w, scene.grid.cells))
    )
    if not ok:
        fail("window", w, f"None or {dim} integers, cells per axis in 1..grid.cells = {list(scene.grid.cells)}")
    object.__setattr__(scene, "window", tuple(int(c) for c in w))


def check_couplings(scene: SceneFields) -> None:
    """Interface forces (all fields, or a list of >= 2), the continuity form, the closure's
    fragmentation, and the schemes that several fields and the closure need."""
    if not isinstance(scene.interface_forces, bool):
        try:
            sub = tuple(sorted(set(int(k) for k in scene.interface_forces)))
            ok = all(is_integer(k) for k in scene.interface_forces)
        except (TypeError, ValueError):
            ok = False
        if not ok or len(sub) < 2 or not all(0 <= k < scene.n_fields for k in sub):
            fail(
                "effects.interface_forces",
                scene.interface_forces,
                f"true | false | a list of >= 2 velocity fields in 0..{scene.n_fields - 1} that share the common pressure",
            )
        object.__setattr__(scene, "interface_forces", True if len(sub) == scene.n_fields else sub)
    if scene.continuity not in CONTINUITY:
        fail("effects.continuity", scene.continuity, " | ".join(repr(c) for c in CONTINUITY))
    if scene.continuity == "transport" and not scene.continuity_possible:
        fail(
            "effects.continuity",
            scene.continuity,
            "'auto' | 'off' unless the scene has >= 2 velocity fields with interface forces and transfer = 'musl'",
        )
    if scene.fragmentation not in FRAGMENTATION:
        fail("effects.fragmentation", scene.fragmentation, " | ".join(repr(f) for f in FRAGMENTATION))
    if scene.has_closure and scene.ambient_pressure is not None:
        fail(
            "effects.ambient_pressure",
            scene.ambient_pressure,
            "unset (None) with the closure (effects.c_h): its fragments relax to the pressure of the void (E8)",
        )
    if scene.has_closure and scene.transfer == "apic":
        fail("effects.c_h", scene.c_h, "only with the musl / seed updates (not with transfer = 'apic')")
    if scene.n_fields > 1 and (scene.shape == "bspline2" or scene.transfer == "apic"):
        fail("shape", scene.shape, "'ddmp' or 'linear' (not apic) when phases use several velocity fields")


def check_boundary(scene: SceneFields) -> None:
    """A Boundary whose faces are the grid's, with fewer wall layers than the grid has cells."""
    if not isinstance(scene.boundary, Boundary):
        fail("boundary", scene.boundary, "a Boundary")
    dim = scene.dim
    for face, kind in scene.boundary.faces:
        if AXES.index(face.split("_")[0]) >= dim:
            fail(f"boundary.{face}", kind, f"faces of the {dim}D grid's axes {FACE_NAMES[: 2 * dim]}")
    for k in range(dim):
        sides = sum(scene.boundary.kind(k, side) != "free" for side in ("lo", "hi"))
        if sides * scene.boundary.layers > scene.grid.cells[k]:
            fail(
                "boundary.layers",
                scene.boundary.layers,
                f"at most {scene.grid.cells[k] // sides} on axis {AXES[k]} ({scene.grid.cells[k]} cells, walls on {sides} "
                "side(s)): more would constrain every node of the axis",
            )


def check_run(scene: SceneFields) -> None:
    """The default end time and number of outputs."""
    t_end = as_float("t_end", scene.t_end)
    if not t_end > 0:
        fail("t_end", t_end, "> 0 s")
    object.__setattr__(scene, "t_end", t_end)
    if not isinstance(scene.n_out, int) or isinstance(scene.n_out, bool) or scene.n_out < 1:
        fail("output.n_out", scene.n_out, "an integer >= 1")


def check_drag_heating(scene: SceneFields) -> None:
    """Drag heating needs an exchange to heat with and the 'musl' update."""
    if not isinstance(scene.drag_heating, bool):
        fail("effects.drag_heating", scene.drag_heating, "true | false")
    if scene.drag_heating and not scene.has_exchange:
        fail(
            "effects.drag_heating",
            scene.drag_heating,
            "false unless the scene has an exchange (effects.drag or "
            "effects.linear_drag, and phases in two or more velocity fields)",
        )
    if scene.drag_heating and scene.transfer != "musl":
        fail(
            "effects.drag_heating",
            scene.drag_heating,
            "false unless transfer = 'musl' (the heat is the drag's work at the remap of the step's own positions)",
        )


def check_window_use(scene: SceneFields) -> None:
    """A window only where the scene has per-field grid operators to compute on it."""
    if scene.window is not None and scene.shape != "ddmp" and not scene.has_interface_forces and not scene.has_exchange:
        fail(
            "window",
            list(scene.window),
            "None unless the scene has DDMP operators (shape 'ddmp', or interface "
            "forces between velocity fields) or an exchange between fields",
        )
