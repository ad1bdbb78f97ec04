"""Only the effects a scene names are in the traced step: an effect that is off leaves its Params
leaf unread (a dead input of the step's jaxpr) and adds no equations."""

import dataclasses

import jax
import pytest

import jaxmpm
from jaxmpm.model.scene import Boundary
from jaxmpm.step import STAGE_PARTS, STAGES


def _base():
    return jaxmpm.load_scene("elastic_impact", resolution=0.2)


def _jaxpr_and_leaf_used(scene, leaf_of):
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    step = jaxmpm.make_step(scene)
    closed = jax.make_jaxpr(step)(params, state)
    leaves = jax.tree.leaves((params, state))
    target = leaf_of(params)
    idx = [i for i, a in enumerate(leaves) if a is target]
    assert len(idx) == 1
    var = closed.jaxpr.invars[idx[0]]
    used = any(var in e.invars for e in closed.jaxpr.eqns) or var in closed.jaxpr.outvars
    return closed, used


EFFECTS = {
    "gravity": (dict(gravity=(0.0, -9.81)), lambda p: p.gravity),
    "gravity_ramp": (dict(gravity=(0.0, -9.81), gravity_ramp=0.1), lambda p: p.gravity_ramp),
    "damping": (dict(damping=0.5), lambda p: p.damping),
    "body_force": (dict(body_force=True), lambda p: p.body_force["disk_a"]),
    "ambient_pressure": (dict(ambient_pressure=101325.0), lambda p: p.ambient_pressure),
}


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_effect_off_is_not_traced(effect):
    on_kw, leaf = EFFECTS[effect]
    off = _base()
    on = dataclasses.replace(off, **on_kw)
    jaxpr_off, used_off = _jaxpr_and_leaf_used(off, leaf)
    jaxpr_on, used_on = _jaxpr_and_leaf_used(on, leaf)
    assert not used_off, f"{effect} is off but its Param is read by the step"
    if effect != "gravity_ramp":
        assert used_on, f"{effect} is on but its Param is not read"
    assert len(jaxpr_on.jaxpr.eqns) > len(jaxpr_off.jaxpr.eqns)


def test_gravity_ramp_read_only_with_gravity():
    scene = dataclasses.replace(_base(), gravity=(0.0, -9.81))
    _, used = _jaxpr_and_leaf_used(scene, lambda p: p.gravity_ramp)
    assert used


def _n_eqns(scene):
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    return len(str(jax.make_jaxpr(jaxmpm.make_step(scene))(params, state)).splitlines())


def test_walls_and_ddmp_add_code_only_when_named():
    free = dataclasses.replace(_base(), shape="linear")
    walls = dataclasses.replace(free, boundary=Boundary(faces=(("y_lo", "fixed"),)))
    ddmp = dataclasses.replace(free, shape="ddmp")
    assert _n_eqns(walls) > _n_eqns(free)
    assert _n_eqns(ddmp) > _n_eqns(free)


def test_nonzero_param_of_an_absent_effect_is_an_error():
    scene = _base()
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    bad = dataclasses.replace(params, gravity=params.gravity.at[1].set(-9.81))
    with pytest.raises(ValueError, match="gravity"):
        jaxmpm.simulate(scene, bad, state, t_end=0.01, progress=False)


@pytest.mark.parametrize(
    "name, options, parts",
    [
        ("debris_cloud", dict(resolution=0.75, fields=2), STAGE_PARTS),
        ("elastic_impact", {}, ("ddmp_operators", "stress_force", "remap", "velocity_gradient")),
        ("mpm88", {}, ()),
    ],
)
def test_stages_are_named_in_the_step(name, options, parts):
    """Each stage of the step (and each part of the grid update and the grid-to-particle stage
    that the scene has) carries its name into the lowered program, where a profile reads it
    (benchmarks/profile_step.py); a part the scene does not have is not named."""
    scene = jaxmpm.load_scene(name, **options)
    params = jaxmpm.default_params(scene)
    text = jax.jit(jaxmpm.make_step(scene)).lower(params, jaxmpm.init_state(scene, params)).as_text(debug_info=True)
    for label in STAGES + STAGE_PARTS:
        assert (f"/{label}/" in text) == (label in STAGES or label in parts), (name, label)
