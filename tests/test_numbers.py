"""The table of the effects' numbers (jaxmpm.model.numbers): Params' fields, their defaults and
checks and Scene's validation are built from it, and the old Params names still work, with a
DeprecationWarning naming the new one."""

import dataclasses
import re
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm import Box, Grid, Material, Phase, Scene
from jaxmpm.model.numbers import NUMBERS, OLD_NAMES
from jaxmpm.model.params import FIELDS, check_params

GAS = Material.make("gas", "linear_fluid", rho0=10.0, K=1.0e7)


def two_gases(**kw):
    phases = (
        Phase("a", "gas", Box((0.2, 0.2), (0.4, 0.4)), field=0),
        Phase("b", "gas", Box((0.5, 0.5), (0.7, 0.7)), field=1),
    )
    return Scene(grid=Grid(cells=(10, 10), h=0.1), materials=(GAS,), phases=phases, **kw)


# each number switched on (with what it acts with), so that only its own range is at stake
ON = dict(gravity_ramp=dict(gravity=(0.0, -9.8)), drag_length=dict(drag=1.0))


def below_range(n):
    """A value just outside the number's range (its lower bound where open, else below it)."""
    x = n.low if n.low_open else n.low - 1.0
    return (x, 0.0) if n.size == 2 else x


RANGED = [n for n in NUMBERS if np.isfinite(n.low)]


def test_the_table_names_every_params_field_and_nothing_else():
    names = [n.name for n in NUMBERS]
    assert len(set(names)) == len(names)
    assert set(FIELDS) == {"phases", "body_force", *names}
    assert [f.name for f in dataclasses.fields(jaxmpm.Params)] == list(FIELDS)
    assert not set(OLD_NAMES) & set(FIELDS)


def test_every_number_is_a_scene_field_of_the_same_name():
    scene_fields = {f.name for f in dataclasses.fields(Scene)}
    assert {n.name for n in NUMBERS} <= scene_fields


def test_default_params_holds_the_table_defaults_where_the_effects_are_off():
    scene = two_gases()
    params = jaxmpm.default_params(scene)
    for n in NUMBERS:
        value = np.asarray(getattr(params, n.name))
        if n.name == "cfl":
            assert float(value) == scene.cfl == pytest.approx(n.default)
        elif n.name == "artificial_viscosity":  # fluids take FLUID_VISCOSITY by default
            assert value.tolist() == list(scene.viscosity)
        elif n.default == "h":
            assert float(value) == pytest.approx(scene.grid.h)
        else:
            assert np.all(value == n.default), n.name
    check_params(scene, params)


@pytest.mark.parametrize("n", RANGED, ids=lambda n: n.name)
def test_a_scene_value_out_of_range_names_the_field_and_the_range(n):
    bad = below_range(n)
    shown = re.escape(repr(list(bad) if n.size == 2 else float(bad)))
    with pytest.raises(
        ValueError, match=rf"^{re.escape(n.key)} = {shown} is invalid: allowed {re.escape(n.allowed(2))}$"
    ):
        two_gases(**{**ON.get(n.name, {}), n.name: bad})


@pytest.mark.parametrize("n", RANGED, ids=lambda n: n.name)
def test_a_params_value_out_of_range_names_the_field_and_the_range(n):
    scene = two_gases(**ON.get(n.name, {}), **({n.name: 1.0} if n.size == 0 and n.name != "cfl" else {}))
    params = jaxmpm.default_params(scene)
    bad = jnp.asarray(below_range(n), dtype=params.cfl.dtype)
    allowed = n.params_text or n.allowed(2)
    with pytest.raises(ValueError, match=rf"^params\.{n.name} = .* is invalid: allowed {re.escape(allowed)}$"):
        check_params(scene, dataclasses.replace(params, **{n.name: bad}))
    with pytest.raises(ValueError, match=rf"^params\.{n.name} = nan is invalid" if n.size == 0 else "invalid"):
        check_params(scene, dataclasses.replace(params, **{n.name: jnp.full_like(bad, jnp.nan)}))


def test_cfl_above_its_range_in_scene_and_params():
    with pytest.raises(ValueError, match=r"^cfl = 1\.5 is invalid: allowed \(0, 1\]$"):
        two_gases(cfl=1.5)
    scene = two_gases()
    with pytest.raises(ValueError, match=r"^params\.cfl = 1\.5 is invalid: allowed \(0, 1\]$"):
        check_params(scene, dataclasses.replace(jaxmpm.default_params(scene), cfl=jnp.asarray(1.5)))


@pytest.mark.parametrize("n", [n for n in NUMBERS if n.switch_attribute], ids=lambda n: n.name)
def test_a_params_value_whose_effect_is_off_is_refused(n):
    scene = two_gases(artificial_viscosity=None) if n.name != "artificial_viscosity" else two_gases()
    if n.name == "artificial_viscosity":  # the gases take a viscosity by default: a solid takes none
        solid = Material.make("m", "hypoelastic", rho0=1000.0, E=1e6, nu=0.3)
        scene = Scene(
            grid=Grid(cells=(10, 10), h=0.1), materials=(solid,), phases=(Phase("s", "m", scene.phases[0].geometry),)
        )
    params = jaxmpm.default_params(scene)
    other = jnp.asarray(getattr(params, n.name)) + 0.5
    with pytest.raises(ValueError, match=rf"^params\.{n.name} \(the scene has no {re.escape(n.off)}\)"):
        check_params(scene, dataclasses.replace(params, **{n.name: other}))


def test_scene_numbers_that_act_with_another_effect_only_with_it():
    with pytest.raises(
        ValueError, match=r"effects\.gravity_ramp = 1\.0 is invalid: allowed only with effects\.gravity"
    ):
        two_gases(gravity_ramp=1.0)
    with pytest.raises(ValueError, match=r"effects\.drag_length = 0\.1 is invalid: allowed only with effects\.drag"):
        two_gases(drag_length=0.1)


def test_the_old_params_names_warn_naming_the_new_one_and_hold_the_same_number():
    scene = two_gases(drag=2.0)
    params = jaxmpm.default_params(scene)
    with pytest.warns(DeprecationWarning, match=r"params\.drag_coefficient is deprecated: it is params\.drag"):
        assert params.drag_coefficient is params.drag
    with pytest.warns(DeprecationWarning, match=r"params\.drag_coefficient .* params\.drag"):
        p = dataclasses.replace(params, drag_coefficient=jnp.asarray(3.0))
    assert float(p.drag) == 3.0
    with pytest.warns(DeprecationWarning, match=r"params\.av_linear .* params\.artificial_viscosity\[0\]"):
        p = dataclasses.replace(params, av_linear=jnp.asarray(0.25))
    assert np.asarray(p.artificial_viscosity).tolist() == [0.25, params.artificial_viscosity[1]]
    with pytest.warns(DeprecationWarning, match=r"params\.av_quadratic .* params\.artificial_viscosity\[1\]"):
        assert float(p.av_quadratic) == float(params.artificial_viscosity[1])
    with pytest.warns(DeprecationWarning, match=r"params\.drag_coefficient .* params\.drag"):
        batch = jaxmpm.batch.sweep(params, drag_coefficient=[1.0, 4.0])
    assert np.asarray(batch.drag).tolist() == [1.0, 4.0]
    with pytest.warns(DeprecationWarning, match=r"params\.av_quadratic"):
        batch = jaxmpm.batch.sweep(params, av_quadratic=[1.0, 3.0])
    assert np.asarray(batch.artificial_viscosity).tolist() == [[0.5, 1.0], [0.5, 3.0]]


def test_the_new_names_do_not_warn():
    params = jaxmpm.default_params(two_gases(drag=2.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = dataclasses.replace(params, drag=jnp.asarray(3.0), artificial_viscosity=jnp.asarray([1.0, 2.0]))
        jaxmpm.batch.sweep(p, drag=[1.0, 2.0])
    with pytest.raises(TypeError, match=r"Params\(drag_coefficent\) is invalid: allowed the fields"):
        dataclasses.replace(params, drag_coefficent=1.0)
