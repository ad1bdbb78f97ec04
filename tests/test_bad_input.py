"""The table of every bad input we try and the message it gets (issue: hard cases and bad input).

Each row: a kind of mistake, what is done, and a regular expression the error message must match
(naming the field and the allowed range). `python tests/test_bad_input.py` prints the table with
the actual messages as Markdown (docs/bad_input.md is that output).
"""

import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm import Boundary, Box, Grid, Material, Phase, Scene, Sphere
from jaxmpm.io.scenefile import scene_from_toml
from test_validation import SCENE_TOML

M = Material.make("m", "hypoelastic", rho0=1000.0, E=1e6, nu=0.3)
GAS = Material.make("gas", "ideal_gas", rho0=1.0, gamma=1.4, p0=1e5)


def scene(**kw):
    args = dict(
        grid=Grid(cells=(10, 10), h=0.1), materials=(M,), phases=(Phase("block", "m", Box((0.2, 0.2), (0.6, 0.6))),)
    )
    args.update(kw)
    return Scene(**args)


def two_fields(**kw):
    return scene(
        phases=(
            Phase("a", "m", Box((0.2, 0.2), (0.4, 0.4)), field=0),
            Phase("b", "m", Box((0.5, 0.5), (0.7, 0.7)), field=1),
        ),
        **kw,
    )


def params_of(**changes):
    s = scene()
    return s, dataclasses.replace(jaxmpm.default_params(s), **changes)


def run_with_params(**changes):
    s, p = params_of(**changes)
    jaxmpm.init_state(s, p)


def run_with_state(**changes):
    s = scene()
    p = jaxmpm.default_params(s)
    st = jaxmpm.init_state(s, p)
    jaxmpm.simulate(s, p, dataclasses.replace(st, **{k: f(st) for k, f in changes.items()}), progress=False)


def apic_with_state(**changes):
    s = scene(shape="bspline2", transfer="apic")
    p = jaxmpm.default_params(s)
    st = jaxmpm.init_state(s, p)
    jaxmpm.simulate(s, p, dataclasses.replace(st, **{k: f(st) for k, f in changes.items()}), progress=False)


def simulate_with(**kw):
    s = scene()
    p = jaxmpm.default_params(s)
    jaxmpm.simulate(s, p, jaxmpm.init_state(s, p), progress=False, **kw)


def plan_with(params=lambda p: p, state=lambda st: st, **kw):
    s = scene()
    p = jaxmpm.default_params(s)
    return jaxmpm.plan_steps(s, params(p), state(jaxmpm.init_state(s, p)), kw.pop("t_end", 1e-3), **kw)


def ensemble_with(state=None, member=None, **kw):
    """An ensemble of two members of scene() (the second changed by `member`) from the initial state
    changed by `state`."""
    s = scene()
    p = jaxmpm.default_params(s)
    st = jaxmpm.init_state(s, p)
    batch = jaxmpm.batch.stack([p, p if member is None else member(p)])
    jaxmpm.ensemble(s, batch, state=st if state is None else state(st), n_out=1, **{"t_end": 1e-3, **kw})


FILE = SCENE_TOML  # a valid scene file (tests/test_validation.py)

CASES = [
    # --- grid and geometry
    ("grid cells not integers", lambda: Grid(cells=(10.5, 10), h=0.1), r"grid\.cells"),
    ("grid with one cell", lambda: Grid(cells=(1, 10), h=0.1), r"grid\.cells\[0\] = 1 is invalid: allowed >= 2"),
    (
        "grid of 4 dimensions",
        lambda: Grid(cells=(2, 2, 2, 2), h=0.1),
        r"grid\.cells = .* allowed a list of 1 to 3 integers",
    ),
    ("negative cell size", lambda: Grid(cells=(10, 10), h=-0.1), r"grid\.h = -0\.1 is invalid: allowed > 0 m"),
    (
        "box with hi below lo",
        lambda: Box((0.5, 0.2), (0.4, 0.6)),
        r"geometry\.hi\[0\] = 0\.4 is invalid: allowed > geometry\.lo\[0\]",
    ),
    (
        "sphere with negative radius",
        lambda: Sphere((0.5, 0.5), -0.1),
        r"geometry\.radius = -0\.1 is invalid: allowed > 0 m",
    ),
    (
        "non-finite coordinate",
        lambda: Box((0.0, float("nan")), (0.5, 0.5)),
        r"geometry\.lo = .* allowed finite numbers",
    ),
    (
        "geometry of the wrong dimension",
        lambda: scene(phases=(Phase("b", "m", Box((0.2,), (0.6,))),)),
        r"phase\.b\.geometry = .* allowed 2 coordinates per point",
    ),
    (
        "particle outside the grid",
        lambda: scene(phases=(Phase("b", "m", Box((0.5, 0.5), (1.2, 0.6))),)),
        r"phase\.b\.geometry = .* is invalid: allowed inside the grid: axis x in \[0\.0, 1\.0\] m",
    ),
    (
        "phase with no particle",
        lambda: scene(phases=(Phase("b", "m", Sphere((0.5, 0.5), 1e-4), ppc=1),)),
        r"phase\.b\.geometry = .* holds no particle",
    ),
    ("cell size given as a string", lambda: Grid(cells=(10, 10), h="5"), r"grid\.h = '5' is invalid: allowed a number"),
    (
        "cell size given as a list",
        lambda: Grid(cells=(10, 10), h=[0.1]),
        r"grid\.h = \[0\.1\] is invalid: allowed a number",
    ),
    (
        "velocity given as a string of digits",
        lambda: Phase("b", "m", Box((0.2, 0.2), (0.6, 0.6)), velocity="12"),
        r"phase\.b\.velocity = '12' is invalid: allowed a list of numbers",
    ),
    (
        "coordinates given as strings",
        lambda: Box(("0", "0"), (0.5, 0.5)),
        r"geometry\.lo = .* is invalid: allowed a list of numbers",
    ),
    (
        "phases given as names",
        lambda: scene(phases=("block",)),
        r"phases = \('block',\) is invalid: allowed a tuple of Phase",
    ),
    (
        "materials given as keys",
        lambda: scene(materials=("m",)),
        r"materials = \('m',\) is invalid: allowed a tuple of Material",
    ),
    # --- phases and fields
    (
        "phase name not an identifier",
        lambda: Phase("a b", "m", Box((0.2, 0.2), (0.6, 0.6))),
        r"phase\.name = 'a b' is invalid",
    ),
    (
        "two bodies in one place",
        lambda: scene(
            phases=(Phase("a", "m", Box((0.2, 0.2), (0.6, 0.6))), Phase("b", "m", Box((0.4, 0.4), (0.8, 0.8))))
        ),
        r"phase\.a\.geometry overlaps phase\.b\.geometry in velocity field 0 \(e\.g\. at .* m\), where their volume fractions sum to 2",
    ),
    (
        "two phases with one name",
        lambda: scene(
            phases=(Phase("b", "m", Box((0.2, 0.2), (0.4, 0.4))), Phase("b", "m", Box((0.5, 0.5), (0.7, 0.7))))
        ),
        r"phase\.name = 'b' is invalid: allowed unique names",
    ),
    (
        "negative field index",
        lambda: Phase("b", "m", Box((0.2, 0.2), (0.6, 0.6)), field=-1),
        r"phase\.b\.field = -1 is invalid: allowed an integer >= 0",
    ),
    (
        "field that does not exist (gap)",
        lambda: scene(phases=(Phase("b", "m", Box((0.2, 0.2), (0.6, 0.6)), field=1),)),
        r"phase\.b\.field = 1 is invalid: allowed fields numbered 0\.\.0 without gaps",
    ),
    (
        "too many particles per cell",
        lambda: Phase("b", "m", Box((0.2, 0.2), (0.6, 0.6)), ppc=9),
        r"phase\.b\.ppc = 9 is invalid: allowed an integer in \[1, 8\]",
    ),
    (
        "volume fraction above 1",
        lambda: Phase("b", "m", Box((0.2, 0.2), (0.6, 0.6)), fraction=1.5),
        r"phase\.b\.fraction = 1\.5 is invalid: allowed \(0, 1\]",
    ),
    (
        "unknown material key",
        lambda: scene(phases=(Phase("b", "unobtainium", Box((0.2, 0.2), (0.6, 0.6))),)),
        r"phase\.b\.material = 'unobtainium' is an unknown material key: known keys are \[.*'al2024'",
    ),
    # --- materials
    (
        "negative density",
        lambda: Material.make("x", "hypoelastic", rho0=-1.0, E=1e6, nu=0.3),
        r"materials\.x\.rho0 = -1\.0 is invalid: allowed \(0, inf\) kg/m\^3",
    ),
    (
        "negative density, plain constructor",
        lambda: Material("x", "hypoelastic", (("rho0", -1.0), ("E", 1e6), ("nu", 0.3))),
        r"materials\.x\.rho0 = -1\.0 is invalid: allowed \(0, inf\) kg/m\^3",
    ),
    (
        "constants not (name, value) pairs",
        lambda: Material("x", "hypoelastic", (1000.0, 1e6, 0.3)),
        r"materials\.x\.constants = .* is invalid: allowed a tuple of \(name, value\) pairs",
    ),
    (
        "a constant given twice",
        lambda: Material("x", "hypoelastic", (("rho0", 1.0), ("E", 1e6), ("nu", 0.3), ("E", 2e6))),
        r"materials\.x\.E is given twice: allowed each constant once",
    ),
    (
        "zero Young's modulus",
        lambda: Material.make("x", "hypoelastic", rho0=1.0, E=0.0, nu=0.3),
        r"materials\.x\.E = 0\.0 is invalid: allowed \(0, inf\) Pa",
    ),
    (
        "Poisson's ratio 0.5",
        lambda: Material.make("x", "hypoelastic", rho0=1.0, E=1.0, nu=0.5),
        r"materials\.x\.nu = 0\.5 is invalid: allowed \(-1, 0\.5\)",
    ),
    (
        "negative relaxation time",
        lambda: Material.make("x", "maxwell", rho0=1.0, E=1.0, nu=0.3, tau=-1.0),
        r"materials\.x\.tau = -1\.0 is invalid: allowed \(0, inf\) s",
    ),
    (
        "gas gamma <= 1",
        lambda: Material.make("x", "ideal_gas", rho0=1.0, gamma=1.0, p0=0.0),
        r"materials\.x\.gamma = 1\.0 is invalid: allowed \(1, inf\)",
    ),
    (
        "Hugoniot slope s <= 0",
        lambda: Material.make("x", "mie_gruneisen", rho0=1.0, c0=1.0, s=0.0, gamma0=2.0, a=0.0),
        r"materials\.x\.s = 0\.0 is invalid",
    ),
    (
        "hardening exponent n > 1",
        lambda: Material.make(
            "x", "linear+johnson_cook", rho0=1.0, K=1.0, G=1.0, A=1.0, B=1.0, n=2.0, C=0.0, epsdot0=1.0
        ),
        r"materials\.x\.n = 2\.0 is invalid: allowed \(0, 1\]",
    ),
    (
        "missing constant",
        lambda: Material.make("x", "hypoelastic", rho0=1.0, E=1.0),
        r"materials\.x\.nu is missing: model 'hypoelastic' needs",
    ),
    (
        "constant of another model",
        lambda: Material.make("x", "hypoelastic", rho0=1.0, E=1.0, nu=0.3, K=1.0),
        r"materials\.x\.K is not a constant of model 'hypoelastic'",
    ),
    (
        "constant not a number",
        lambda: Material.make("x", "hypoelastic", rho0=1.0, E="hard", nu=0.3),
        r"materials\.x\.E = 'hard' is invalid: allowed a number",
    ),
    (
        "unknown model kind",
        lambda: Material.make("x", "rubbery", rho0=1.0),
        r"materials\.x\.model = 'rubbery' is invalid: allowed linear_elastic",
    ),
    (
        "unknown part of a composition",
        lambda: Material.make("x", "ideal_gas+rubber", rho0=1.0),
        r"part 'rubber' is unknown",
    ),
    (
        "composition out of order",
        lambda: Material.make("x", "linear+spall+elastic", rho0=1.0),
        r"out of order: write 'linear\+elastic\+spall'",
    ),
    (
        "two strength models",
        lambda: Material.make("x", "linear+elastic+von_mises", rho0=1.0),
        r"names 2 strength models",
    ),
    (
        "library model the table cannot fill",
        lambda: jaxmpm.materials.library_material("al2024", "mie_gruneisen+von_mises"),
        r"library key 'al2024' has no 'Y'",
    ),
    # --- scene options
    (
        "unknown shape function",
        lambda: scene(shape="cubic"),
        r"shape = 'cubic' is invalid: allowed linear \| ddmp \| bspline2",
    ),
    ("unknown transfer", lambda: scene(transfer="flip"), r"transfer = 'flip' is invalid: allowed musl \| seed"),
    (
        "unknown energy update",
        lambda: scene(energy_update="exact"),
        r"energy_update = 'exact' is invalid: allowed midpoint \| compatible",
    ),
    (
        "compatible energy update with the seed's remap",
        lambda: scene(energy_update="compatible", transfer="seed"),
        r"energy_update = 'compatible' is invalid: allowed 'compatible' only with transfer = 'musl' \(here 'seed'\)",
    ),
    (
        "APIC without B-splines",
        lambda: scene(transfer="apic"),
        r"transfer = 'apic' is invalid: allowed 'apic' only with shape = 'bspline2'",
    ),
    (
        "B-splines with two fields",
        lambda: two_fields(shape="bspline2"),
        r"shape = 'bspline2' is invalid: allowed 'ddmp' or 'linear'",
    ),
    (
        "gravity given as a string",
        lambda: scene(gravity="09"),
        r"effects\.gravity = '09' is invalid: allowed a list of numbers",
    ),
    (
        "gravity with the wrong length",
        lambda: scene(gravity=(0.0, -9.8, 0.0)),
        r"effects\.gravity = .* allowed a list of 2 numbers",
    ),
    (
        "negative gravity ramp",
        lambda: scene(gravity=(0.0, -9.8), gravity_ramp=-1.0),
        r"effects\.gravity_ramp = -1\.0 is invalid: allowed >= 0 s",
    ),
    (
        "gravity ramp without gravity",
        lambda: scene(gravity_ramp=1.0),
        r"effects\.gravity_ramp = 1\.0 is invalid: allowed only with effects\.gravity",
    ),
    (
        "drag length without drag",
        lambda: two_fields(drag_length=0.01),
        r"effects\.drag_length = 0\.01 is invalid: allowed only with effects\.drag",
    ),
    (
        "drag heating without an exchange",
        lambda: two_fields(drag_heating=True),
        r"effects\.drag_heating = True is invalid: allowed false unless the scene has an exchange",
    ),
    (
        "drag heating with the seed's remap",
        lambda: two_fields(drag=1.0, transfer="seed", drag_heating=True),
        r"effects\.drag_heating = True is invalid: allowed false unless transfer = 'musl'",
    ),
    (
        "drag heating given as a number",
        lambda: two_fields(drag=1.0, drag_heating=1),
        r"effects\.drag_heating = 1 is invalid: allowed true \| false",
    ),
    ("negative damping", lambda: scene(damping=-1.0), r"effects\.damping = -1\.0 is invalid: allowed >= 0 1/s"),
    ("negative drag coefficient", lambda: two_fields(drag=-1.0), r"effects\.drag = -1\.0 is invalid: allowed >= 0"),
    (
        "zero drag length",
        lambda: two_fields(drag=1.0, drag_length=0.0),
        r"effects\.drag_length = 0\.0 is invalid: allowed > 0 m",
    ),
    ("C_h <= 0", lambda: scene(c_h=0.0), r"effects\.c_h = 0\.0 is invalid: allowed > 0"),
    (
        "negative artificial viscosity",
        lambda: scene(
            materials=(GAS,), phases=(Phase("g", "gas", Box((0.2, 0.2), (0.6, 0.6))),), artificial_viscosity=(-0.1, 1.0)
        ),
        r"effects\.artificial_viscosity = \[-0\.1, 1\.0\] is invalid",
    ),
    (
        "artificial viscosity on a total-stress model",
        lambda: scene(artificial_viscosity=(0.5, 2.0)),
        r"effects\.artificial_viscosity .* only with equation-of-state models and linear_fluid: phase 'block' uses 'hypoelastic'",
    ),
    (
        "density diffusion out of range",
        lambda: scene(density_diffusion=1.5),
        r"effects\.density_diffusion = 1\.5 is invalid: allowed \[0, 1\] \(dimensionless; 0: off\)",
    ),
    (
        "density diffusion not a number",
        lambda: scene(density_diffusion="strong"),
        r"effects\.density_diffusion = 'strong' is invalid",
    ),
    (
        "unknown boundary face",
        lambda: Boundary(faces=(("z_top", "slip"),)),
        r"boundary\.z_top = 'slip' is invalid: allowed face names",
    ),
    (
        "unknown boundary kind",
        lambda: Boundary(faces=(("x_lo", "sticky"),)),
        r"boundary\.x_lo = 'sticky' is invalid: allowed free \| slip \| separating \| fixed",
    ),
    (
        "wall on an axis the grid does not have",
        lambda: scene(boundary=Boundary(faces=(("z_lo", "fixed"),))),
        r"boundary\.z_lo = 'fixed' is invalid: allowed faces of the 2D grid's axes",
    ),
    (
        "wall layers filling an axis",
        lambda: scene(
            grid=Grid(cells=(10, 6), h=0.1),
            phases=(Phase("b", "m", Box((0.2, 0.2), (0.6, 0.4))),),
            boundary=Boundary(faces=(("y_lo", "fixed"), ("y_hi", "slip")), layers=4),
        ),
        r"boundary\.layers = 4 is invalid: allowed at most 3 on axis y",
    ),
    ("CFL above 1", lambda: scene(cfl=1.5), r"cfl = 1\.5 is invalid: allowed \(0, 1\]"),
    ("negative end time", lambda: scene(t_end=-1.0), r"t_end = -1\.0 is invalid: allowed > 0 s"),
    ("zero outputs", lambda: scene(n_out=0), r"output\.n_out = 0 is invalid: allowed an integer >= 1"),
    # --- Params
    (
        "Params constant out of range",
        lambda: run_with_params(
            phases={"block": {"rho0": jnp.asarray(-1.0), "E": jnp.asarray(1e6), "nu": jnp.asarray(0.3)}}
        ),
        r"params\.phases\['block'\]\['rho0'\] = -1\.0 is invalid: allowed \(0, inf\)",
    ),
    (
        "Params missing a constant",
        lambda: run_with_params(phases={"block": {"rho0": jnp.asarray(1.0), "E": jnp.asarray(1e6)}}),
        r"params\.phases\['block'\]\['nu'\] is missing",
    ),
    (
        "Params for another scene",
        lambda: run_with_params(phases={"other": {}}),
        r"params\.phases has phases \['other'\]: the scene has \['block'\]",
    ),
    (
        "Params CFL out of range",
        lambda: run_with_params(cfl=jnp.asarray(2.0)),
        r"params\.cfl = 2\.0 is invalid: allowed \(0, 1\]",
    ),
    (
        "Params gravity of the wrong length",
        lambda: run_with_params(gravity=jnp.zeros(3)),
        r"params\.gravity = .* allowed 2 finite numbers",
    ),
    (
        "Params gravity without the effect",
        lambda: run_with_params(gravity=jnp.asarray([0.0, -9.8])),
        r"params\.gravity \(the scene has no gravity effect\)",
    ),
    (
        "Params negative ramp",
        lambda: run_with_params(gravity_ramp=jnp.asarray(-1.0)),
        r"params\.gravity_ramp = -1\.0 is invalid: allowed >= 0 s",
    ),
    (
        "Params negative drag",
        lambda: run_with_params(drag=jnp.asarray(-1.0)),
        r"params\.drag = -1\.0 is invalid: allowed >= 0",
    ),
    (
        "Params non-finite C_h",
        lambda: run_with_params(c_h=jnp.asarray(float("nan"))),
        r"params\.c_h = nan is invalid: allowed > 0",
    ),
    (
        "Params constant of the wrong shape",
        lambda: run_with_params(cfl=jnp.full(3, 0.3)),
        r"params\.cfl has shape \(3,\): allowed a number",
    ),
    (
        "Params constant not a number",
        lambda: jaxmpm.default_params(scene()).with_constant("block", "E", "hard"),
        r"params\.phases\['block'\]\['E'\] = 'hard' is invalid: allowed a number",
    ),
    (
        "Params closure constant without the closure",
        lambda: run_with_params(c_h=jnp.asarray(0.5)),
        r"params\.c_h \(the scene has no closure \(effects\.c_h\)\): set it in the scene",
    ),
    (
        "Params body force of the wrong length",
        lambda: run_with_params(body_force={"block": jnp.zeros(3)}),
        r"params\.body_force\['block'\] = .* allowed 2 finite numbers",
    ),
    (
        "Params non-finite damping",
        lambda: (
            lambda s: jaxmpm.init_state(
                s, dataclasses.replace(jaxmpm.default_params(s), damping=jnp.asarray(float("nan")))
            )
        )(scene(damping=1.0)),
        r"params\.damping = nan is invalid: allowed finite values >= 0 1/s",
    ),
    # --- State
    (
        "negative particle volume",
        lambda: run_with_state(volume=lambda s: s.volume.at[5].set(-1.0)),
        r"state\.volume = -1\.0 of particle 5 \(phase 'block'\) is invalid: allowed > 0 m\^3",
    ),
    (
        "non-finite velocity",
        lambda: run_with_state(v=lambda s: s.v.at[7, 1].set(jnp.nan)),
        r"state\.v of particle 7 \(phase 'block'\) is not finite",
    ),
    (
        "damage above 1",
        lambda: run_with_state(damage=lambda s: s.damage.at[2].set(1.5)),
        r"state\.damage = 1\.5 of particle 2 .* allowed >= 0 and <= 1",
    ),
    (
        "particle moved outside the grid",
        lambda: run_with_state(x=lambda s: s.x.at[0, 0].set(2.0)),
        r"state\.x of particle 0 .* lies outside the grid",
    ),
    (
        "singular deformation gradient",
        lambda: run_with_state(F=lambda s: s.F.at[3].set(0.0)),
        r"state\.F of particle 3 \(phase 'block'\) has det F = 0: allowed det F > 0",
    ),
    ("State of another scene", lambda: run_with_state(x=lambda s: s.x[:-1]), r"state\.x has shape .* the scene needs"),
    (
        "float16 State",
        lambda: run_with_state(
            **{
                k: (lambda s, k=k: getattr(s, k).astype(jnp.float16))
                for k in ("t", "x", "v", "mass", "volume", "F", "stress", "energy")
            }
        ),
        r"state\.t has dtype float16: allowed float32 or float64",
    ),
    (
        "State fields of two dtypes",
        lambda: run_with_state(v=lambda s: s.v.astype(jnp.float32)),
        r"state\.v has dtype float32 and state\.t float64: allowed one dtype for all fields",
    ),
    (
        "float16 State inside jit",
        lambda: (
            lambda s, p, st: jax.jit(
                lambda v: jaxmpm.simulate(s, p, dataclasses.replace(st, v=v), n_steps=2, progress=False)[0].x
            )(st.v.astype(jnp.float16))
        )(scene(), jaxmpm.default_params(scene()), jaxmpm.init_state(scene(), jaxmpm.default_params(scene()))),
        r"state\.v has dtype float16: allowed float32 or float64",
    ),
    (
        "affine matrix C on a scene without APIC",
        lambda: run_with_state(C=lambda s: jnp.zeros(s.x.shape + (2,))),
        r"state\.C is set, but the scene's transfer 'musl' has no affine velocity matrix \(only 'apic' carries C\): allowed None",
    ),
    (
        "APIC state without its affine matrix C",
        lambda: apic_with_state(C=lambda s: None),
        r"state\.C is None: the scene's transfer 'apic' needs the affine velocity matrix C, allowed an array of shape \(\d+, 2, 2\)",
    ),
    (
        "APIC affine matrix of the wrong shape",
        lambda: apic_with_state(C=lambda s: s.C[:, :1]),
        r"state\.C has shape \(\d+, 1, 2\): the scene needs \(\d+, 2, 2\)",
    ),
    # --- running
    (
        "time step above the CFL limit",
        lambda: simulate_with(dt=1.0),
        r"dt = 1 s is above the CFL limit: allowed \(0, .*\] s \(params\.cfl = 0\.3 times cfl_limit = .* s, h = 0\.1 m\)",
    ),
    (
        "end time before the start",
        lambda: simulate_with(t_end=0.0),
        r"t_end = 0\.0 is invalid: allowed a finite time > state\.t = 0\.0 s",
    ),
    ("zero outputs to simulate", lambda: simulate_with(n_out=0), r"n_out = 0 is invalid: allowed an integer >= 1"),
    (
        "infinite end time",
        lambda: simulate_with(t_end=float("inf")),
        r"t_end = inf is invalid: allowed a finite time > state\.t = 0\.0 s",
    ),
    ("zero steps", lambda: simulate_with(n_steps=0), r"n_steps = 0 is invalid: allowed an integer >= 1"),
    ("a fraction of an output", lambda: simulate_with(n_out=2.7), r"n_out = 2\.7 is invalid: allowed an integer >= 1"),
    ("zero steps per chunk", lambda: simulate_with(chunk=0), r"chunk = 0 is invalid: allowed an integer >= 1"),
    (
        "restart file of a fixed-length run",
        lambda: simulate_with(restart_file="never_written.restart.h5", n_steps=4),
        r"restart_file is invalid with n_steps or inside jit/grad/vmap",
    ),
    (
        "debug checks of a fixed-length run",
        lambda: simulate_with(n_steps=4, debug=True),
        r"debug=True is invalid with n_steps or inside jit/grad/vmap",
    ),
    (
        "zero time step to plan",
        lambda: (lambda s, p: jaxmpm.plan_steps(s, p, jaxmpm.init_state(s, p), 1e-3, dt=0.0))(
            scene(), jaxmpm.default_params(scene())
        ),
        r"dt = 0\.0 is invalid: allowed a finite time step > 0 s",
    ),
    (
        "ensemble from a state outside the grid",
        lambda: ensemble_with(state=lambda st: dataclasses.replace(st, x=st.x.at[0, 0].set(5.0))),
        r"state\.x of particle 0 \(phase 'block'\) = .* lies outside the grid",
    ),
    (
        "ensemble member out of range",
        lambda: ensemble_with(member=lambda p: p.with_constant("block", "E", -2e6)),
        r"member 1: params\.phases\['block'\]\['E'\] = -2000000\.0 is invalid",
    ),
    (
        "sweep over words",
        lambda: jaxmpm.batch.sweep(jaxmpm.default_params(scene()), cfl=["a", "b"]),
        r"sweep: cfl = \['a', 'b'\] is invalid: allowed a list of numbers",
    ),
    (
        "sweep of a vector field by numbers",
        lambda: jaxmpm.batch.sweep(jaxmpm.default_params(scene()), gravity=[0.0, -9.8]),
        r"sweep: gravity has shape \(2,\): allowed a list of values of shape \(2,\) \(2-vectors\)",
    ),
    ("restart file as a number", lambda: simulate_with(restart_file=5), r"restart_file = 5 is invalid: allowed a path"),
    (
        "builder option below its range",
        lambda: jaxmpm.load_scene("mpm88", n_grid=3),
        r"mpm88: n_grid = 3 is invalid: allowed an integer >= 27 \(at dim = 2, ppc_scale = 1",
    ),
    (
        "builder options that need too many particles per cell",
        lambda: jaxmpm.load_scene("mpm88", n_grid=32, ppc_scale=2.0),
        r"mpm88: n_grid = 32 is invalid: allowed an integer >= 38 \(at dim = 2, ppc_scale = 2: at most 8 particles per cell per axis",
    ),
    (
        "built-in scene's resolution below its floor",
        lambda: jaxmpm.load_scene("elastic_impact", resolution=0.01),
        r"elastic_impact: resolution = 0\.01 is invalid: allowed a finite number >= 0\.125 \(8 cells across the unit square\)",
    ),
    (
        "built-in scene's option of the wrong kind",
        lambda: jaxmpm.load_scene("rod_penetration", air="yes"),
        r"rod_penetration: air = 'yes' is invalid: allowed true \| false",
    ),
    (
        "gravity moving a particle more than a cell per step",
        lambda: (
            lambda s: jaxmpm.simulate(
                s, jaxmpm.default_params(s), jaxmpm.init_state(s, jaxmpm.default_params(s)), progress=False
            )
        )(jaxmpm.load_scene("elastic_impact", resolution=0.25, overrides={"effects.gravity": [0.0, -1e30]})),
        r"gravity = \[0\.0, -1e\+30\] m/s\^2 is too large for the grid and time step: .* allowed \|gravity\| <= h / dt\^2 = ",
    ),
    (
        "confirmation threshold of zero minutes",
        lambda: simulate_with(max_minutes=0),
        r"max_minutes = 0 is invalid: allowed a number of minutes > 0",
    ),
    (
        "builder cell count as a fraction",
        lambda: jaxmpm.load_scene("vibrating_bar", cells=2.5),
        r"vibrating_bar: cells = 2\.5 is invalid: allowed an integer >= 2",
    ),
    (
        "a folder as a scene file",
        lambda: jaxmpm.load_scene("/"),
        r"scene file .* is a folder: allowed a \.toml scene file or a built-in scene name",
    ),
    (
        "stack of two scenes' Params",
        lambda: jaxmpm.batch.stack([jaxmpm.default_params(scene()), jaxmpm.default_params(two_fields())]),
        r"stack: item 1 has another structure than item 0",
    ),
    (
        "ensemble ending before the start",
        lambda: ensemble_with(t_end=-1.0),
        r"t_end = -1\.0 is invalid: allowed a finite time > state\.t",
    ),
    (
        "unknown checkpointing",
        lambda: simulate_with(n_steps=4, checkpoint="everything"),
        r"checkpoint = 'everything' is invalid: allowed False, True \(= 'nested'\), 'steps', 'nested' or 'auto'",
    ),
    (
        "restart every 0 chunks",
        lambda: simulate_with(restart_file="x.h5", restart_every=0),
        r"restart_every = 0 is invalid: allowed an integer >= 1",
    ),
    (
        "n_steps missing under jit",
        lambda: jax.jit(
            lambda p: jaxmpm.simulate(scene(), p, jaxmpm.init_state(scene(), jaxmpm.default_params(scene())))[0].t
        )(jaxmpm.default_params(scene())),
        r"n_steps is required inside jit/grad/vmap",
    ),
    (
        "one material key for two materials",
        lambda: scene(
            materials=(),
            phases=(
                Phase("a", M, Box((0.2, 0.2), (0.4, 0.4))),
                Phase(
                    "b",
                    dataclasses.replace(M, constants=(("E", 2e6), ("nu", 0.3), ("rho0", 1000.0))),
                    Box((0.5, 0.5), (0.7, 0.7)),
                ),
            ),
        ),
        r"phase\.b\.material = 'm' is invalid: allowed one material per key: phase\.a has another material of key 'm'",
    ),
    (
        "speed overflowing the CFL step",
        lambda: plan_with(state=lambda st: dataclasses.replace(st, v=st.v.at[0].set(1e200))),
        r"the CFL time step at t = 0 s is 0\.0: allowed a finite time > 0 s; a particle or wave speed is not finite or too large",
    ),
    (
        "step plan from bad params",
        lambda: plan_with(params=lambda p: p.with_constant("block", "E", -1.0)),
        r"params\.phases\['block'\]\['E'\] = -1\.0 is invalid: allowed \(0, inf\) Pa",
    ),
    (
        "step plan over the CFL limit",
        lambda: plan_with(dt=1.0),
        r"dt = 1 s is above the CFL limit: allowed \(0, .*\] s",
    ),
    (
        "step plan with a safety below 1",
        lambda: plan_with(safety=0.5),
        r"safety = 0\.5 is invalid: allowed a number >= 1",
    ),
    (
        "ensemble plan with a safety below 1",
        lambda: jaxmpm.ensemble(
            scene(),
            jaxmpm.batch.sweep(jaxmpm.default_params(scene()), cfl=[0.3, 0.4]),
            t_end=1e-3,
            safety=0.5,
            progress=False,
        ),
        r"safety = 0\.5 is invalid: allowed a number >= 1",
    ),
    (
        "end time as a word",
        lambda: simulate_with(t_end="abc"),
        r"t_end = 'abc' is invalid: allowed a number of seconds",
    ),
    (
        "time step as a list",
        lambda: simulate_with(dt=[1e-5]),
        r"dt = \[1e-05\] is invalid: allowed a number of seconds",
    ),
    (
        "end time as numeric text",
        lambda: simulate_with(t_end="0.01"),
        r"t_end = '0\.01' is invalid: allowed a number of seconds",
    ),
    (
        "time step as numeric text",
        lambda: simulate_with(dt="1e-4"),
        r"dt = '1e-4' is invalid: allowed a number of seconds",
    ),
    ("output count as text", lambda: simulate_with(n_out="2"), r"n_out = '2' is invalid: allowed an integer >= 1"),
    (
        "boundary faces as one name",
        lambda: Boundary(faces="y_lo"),
        r"boundary\.faces = 'y_lo' is invalid: allowed pairs \(face, kind\)",
    ),
    (
        "one face given two conditions",
        lambda: Boundary(faces=(("y_lo", "fixed"), ("y_lo", "free"))),
        r"boundary\.y_lo = \['fixed', 'free'\] is invalid: allowed one condition per face",
    ),
    (
        "integer parameters",
        lambda: jaxmpm.default_params(scene(), dtype=jnp.int32),
        r"dtype = int32 is invalid: allowed float32",
    ),
    (
        "grid beyond the memory",
        lambda: (
            lambda s: jaxmpm.simulate(
                s, jaxmpm.default_params(s), jaxmpm.init_state(s, jaxmpm.default_params(s)), progress=False
            )
        )(
            scene(
                grid=Grid(cells=(200_000, 200_000), h=0.1), phases=(Phase("block", "m", Box((0.2, 0.2), (0.6, 0.6))),)
            )
        ),
        r"grid\.cells = \[200000, 200000\] is invalid: its 40,000,400,001 nodes x 1 velocity field\(s\) need more than .* GiB",
    ),
    (
        "--set on a material the scene lacks",
        lambda: jaxmpm.load_scene("elastic_impact", overrides={"materials.rubber.E": 1e6}),
        r"--set materials\.rubber\.E: no material named 'rubber' \(materials: \['soft_elastic'\]",
    ),
    # --- scene files
    (
        "a single [phase] table",
        lambda: scene_from_toml(FILE.replace("[[phase]]", "[phase]")),
        r"phase is a single table \[phase\]: allowed an array of tables, each written \[\[phase\]\]",
    ),
    (
        "unknown key in a scene file",
        lambda: scene_from_toml(FILE.replace("h = 0.1", "h = 0.1\nspacing = 2")),
        r"grid\.spacing is an unknown key",
    ),
    ("malformed TOML", lambda: scene_from_toml(FILE.replace("h = 0.1", "h = = 0.1")), r"malformed TOML: .*line"),
    (
        "wrong type in a scene file",
        lambda: scene_from_toml(FILE.replace("h = 0.1", "h = 'small'")),
        r"grid\.h = 'small' is invalid",
    ),
    (
        "material without a model",
        lambda: scene_from_toml(FILE.replace('model = "linear_elastic"\n', "")),
        r"materials\.m\.model is missing: allowed",
    ),
    (
        "phase without geometry",
        lambda: scene_from_toml(FILE.replace('geometry = { type = "box", lo = [0.2, 0.2], hi = [0.6, 0.6] }', "")),
        r"phase\[0\]\.geometry is missing",
    ),
    (
        "scene file without phases",
        lambda: scene_from_toml(FILE.split("[[phase]]")[0]),
        r"phase is missing: a scene needs at least one \[\[phase\]\]",
    ),
    (
        "library material with an unknown key",
        lambda: scene_from_toml(
            FILE.replace('model = "linear_elastic"\nrho0 = 1000.0\nE = 1e6\nnu = 0.3', 'library = "adamantium"')
        ),
        r"materials\.m\.library = 'adamantium' is invalid: allowed one of \['air', 'al2024'",
    ),
    (
        "a built-in scene's option misspelt",
        lambda: jaxmpm.load_scene("debris_cloud", resolutoin=0.75),
        r"debris_cloud: option\(s\) \['resolutoin'\] are unknown: allowed \['resolution', 'fields'",
    ),
    (
        "a chamber's pressure of zero",
        lambda: jaxmpm.load_scene("debris_cloud", chamber_pressure=0.0),
        r"debris_cloud: chamber_pressure = 0.0 is invalid: allowed a finite number > 0 Pa \(the chamber's air\); "
        r"not given: vacuum",
    ),
    (
        "a negative artificial viscosity coefficient",
        lambda: jaxmpm.load_scene("debris_cloud", artificial_viscosity=(0.2, -1.0)),
        r"debris_cloud: artificial_viscosity = \(0.2, -1.0\) is invalid: allowed \[c_linear, c_quadratic\], two "
        r"finite numbers >= 0",
    ),
    (
        "overrides as text",
        lambda: jaxmpm.load_scene("elastic_impact", overrides="grid.cells=[32,32]"),
        r"overrides = 'grid.cells=\[32,32\]' is invalid: allowed a mapping \{'dotted.key': value\}",
    ),
]


@pytest.mark.parametrize("kind, action, pattern", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gets_a_clear_error(kind, action, pattern):
    with pytest.raises(ValueError, match=pattern):
        action()


def test_particles_beyond_the_memory_are_refused_before_they_are_sampled(monkeypatch):
    """With 1 GiB available, a 2000^2 grid fits (0.5 GiB at 16 numbers per node) but 8 x 8 particles
    per cell over it (2.6e8 positions, 4.1 GiB) do not: the scene is refused before sampling."""
    import jaxmpm.model.memory

    monkeypatch.setattr(jaxmpm.model.memory, "available_memory", lambda: 2**30)
    big = dict(grid=Grid(cells=(2000, 2000), h=1e-3))
    scene(**big, phases=(Phase("block", "m", Box((0.2, 0.2), (0.3, 0.3)), ppc=8),))  # a small body is sampled
    with pytest.raises(
        ValueError,
        match=r"phase\.block\.ppc = 8 is invalid with grid\.h = 0\.001 m: sampling lays "
        r"256,000,000 particle positions over the phase's bounding box, more than 3\.8 GiB",
    ):
        scene(**big, phases=(Phase("block", "m", Box((0.0, 0.0), (2.0, 2.0)), ppc=8),))


def test_an_error_in_a_scene_files_contents_names_the_file(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text(FILE.replace("h = 0.1", "h = 0.1\nspacing = 2"))
    with pytest.raises(ValueError, match=rf"^{path}: grid\.spacing is an unknown key"):
        jaxmpm.load_scene(str(path))
    with pytest.raises(ValueError, match=rf"^{path}: grid\.spacing is an unknown key"):
        jaxmpm.load_scene(str(path), overrides={"t_end": 1.0})


def test_numpy_numbers_are_numbers():
    """NumPy scalars and integer arrays are accepted where Python numbers are (stored as Python
    ints and floats); NumPy booleans are not numbers."""
    m = Material.make("n", "hypoelastic", rho0=np.float32(1000.0), E=np.int64(1_000_000), nu=np.float16(0.25))
    assert m.as_dict() == {"rho0": 1000.0, "E": 1e6, "nu": 0.25}
    g = Grid(cells=np.array([10, 10]), h=np.float32(0.1))
    p = Phase("block", m, Box((0.2, 0.2), (0.6, 0.6)), ppc=np.int64(3), field=np.int32(0))
    s = Scene(grid=g, phases=(p,), window=(np.int64(4), 4))
    assert (s.grid.cells, p.ppc, p.field, s.window) == ((10, 10), 3, 0, (4, 4))
    assert all(type(c) is int for c in s.grid.cells + s.window + (p.ppc, p.field))
    with pytest.raises(ValueError, match=r"materials\.n\.rho0 = np\.True_ is invalid: allowed a number"):
        Material.make("n", "hypoelastic", rho0=np.True_, E=1e6, nu=0.25)


def test_a_sweep_of_a_vector_field_takes_one_vector_per_member():
    batch = jaxmpm.batch.sweep(jaxmpm.default_params(scene()), gravity=[[0.0, -9.81], [0.0, -1.62]], cfl=[0.2, 0.3])
    assert batch.gravity.shape == (2, 2) and batch.cfl.shape == (2,)
    np.testing.assert_array_equal(np.asarray(jaxmpm.batch.member(batch, 1).gravity), [0.0, -1.62])


def test_a_batch_member_out_of_range_is_an_index_error():
    """Indexing a batch clamps silently in JAX; `member` refuses an index outside [-B, B)."""
    batch = jaxmpm.batch.sweep(jaxmpm.default_params(scene()), cfl=[0.1, 0.2])
    assert float(jaxmpm.batch.member(batch, -1).cfl) == 0.2
    for i in (2, -3):
        with pytest.raises(IndexError, match=rf"member {i} is out of range: allowed -2 <= i < 2"):
            jaxmpm.batch.member(batch, i)


def test_a_mixture_may_share_space_and_touching_bodies_may_touch():
    """Bodies that share space with fractions summing to <= 1 (a mixture) and bodies that only touch
    are accepted; their mass is the sum of their parts."""
    half = lambda name, lo, hi: Phase(name, "m", Box(lo, hi), fraction=0.5)
    mix = scene(phases=(half("a", (0.2, 0.2), (0.6, 0.6)), half("b", (0.2, 0.2), (0.6, 0.6))))
    touch = scene(phases=(Phase("a", "m", Box((0.2, 0.2), (0.4, 0.6))), Phase("b", "m", Box((0.4, 0.2), (0.6, 0.6)))))
    one = scene()
    m = lambda s: float(jnp.sum(jaxmpm.init_state(s, jaxmpm.default_params(s)).mass))
    assert m(mix) == pytest.approx(m(one), rel=1e-12) and m(touch) == pytest.approx(m(one), rel=1e-12)


def test_a_fixed_length_run_that_falls_short_of_t_end_says_so():
    """simulate(n_steps=...) with too few steps for t_end: a RuntimeError naming the time reached
    (0.00327 of 0.02 s here), unless allow_short (then final.t says it)."""
    s = scene()
    p = jaxmpm.default_params(s)
    st = jaxmpm.init_state(s, p)
    n = jaxmpm.plan_steps(s, p, st, 2e-2)
    with pytest.raises(
        RuntimeError, match=r"reached only t = .* of t_end = 0\.02 s in n_steps = 3: pass a larger n_steps"
    ):
        jaxmpm.simulate(s, p, st, t_end=2e-2, n_out=2, n_steps=3, progress=False)
    final, _ = jaxmpm.simulate(s, p, st, t_end=2e-2, n_out=2, n_steps=3, progress=False, allow_short=True)
    assert float(final.t) < 0.5 * 2e-2
    final, _ = jaxmpm.simulate(s, p, st, t_end=2e-2, n_out=2, n_steps=n, progress=False)
    assert float(final.t) == pytest.approx(2e-2, rel=1e-9)


def test_the_table_has_at_least_40_kinds_and_the_docs_list_them_all():
    assert len({c[0] for c in CASES}) == len(CASES) >= 40
    import pathlib

    doc = (pathlib.Path(__file__).parents[1] / "docs" / "bad_input.md").read_text()
    missing = [c[0] for c in CASES if f"| {c[0]} |" not in doc]
    assert not missing, f"regenerate docs/bad_input.md (python tests/test_bad_input.py): {missing}"


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    print(
        "# Bad input and the errors it gets\n\nGenerated by `python tests/test_bad_input.py` from the table the tests "
        "check (tests/test_bad_input.py).\n"
    )
    print("| # | bad input | message |\n|---|---|---|")
    for i, (kind, action, _) in enumerate(CASES, 1):
        try:
            action()
            msg = "(no error)"
        except ValueError as e:
            msg = str(e).replace("|", "\\|").replace("\n", " ").replace("[", "\\[")  # [ escaped: not a link
        print(f"| {i} | {kind} | {msg} |")
    sys.exit(0)
