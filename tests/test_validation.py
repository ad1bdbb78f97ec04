"""Bad input gets a clear ValueError that names the field and the allowed range."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.materials import Material
from jaxmpm.model.scene import Box, Grid, Phase, Scene

MAT = Material.make("m", "linear_elastic", rho0=1000.0, E=1e6, nu=0.3)


def _scene(**kw):
    args = dict(
        grid=Grid(cells=(10, 10), h=0.1), phases=(Phase("block", "m", Box((0.2, 0.2), (0.6, 0.6))),), materials=(MAT,)
    )
    args.update(kw)
    return Scene(**args)


@pytest.mark.parametrize("rho0", [0.0, -1000.0])
def test_nonpositive_density(rho0):
    with pytest.raises(ValueError, match=r"materials\.m\.rho0 = .* allowed \(0, inf\) kg/m\^3"):
        Material.make("m", "linear_elastic", rho0=rho0, E=1e6, nu=0.3)
    scene = _scene()
    params = jaxmpm.default_params(scene).with_constant("block", "rho0", rho0)
    with pytest.raises(ValueError, match=r"params\.phases\['block'\]\['rho0'\] = .* allowed \(0, inf\)"):
        jaxmpm.init_state(scene, params)


@pytest.mark.parametrize("E", [0.0, -5.0])
def test_nonpositive_youngs_modulus(E):
    with pytest.raises(ValueError, match=r"materials\.m\.E = .* allowed \(0, inf\) Pa"):
        Material.make("m", "linear_elastic", rho0=1.0, E=E, nu=0.3)


@pytest.mark.parametrize("nu", [0.5, 0.7, -1.0, -2.0])
def test_poisson_ratio_outside_range(nu):
    with pytest.raises(ValueError, match=r"materials\.m\.nu = .* allowed \(-1, 0\.5\)"):
        Material.make("m", "hypoelastic", rho0=1.0, E=1.0, nu=nu)


def test_particle_outside_grid():
    with pytest.raises(ValueError, match=r"phase\.block\.geometry .* inside the grid: axis x in \[0\.0, 1\.0\]"):
        _scene(phases=(Phase("block", "m", Box((0.5, 0.2), (1.3, 0.6))),))


@pytest.mark.parametrize("kind", ["slip", "fixed", "separating", "free"])
def test_a_body_across_a_slip_wall_is_its_mirror_half(kind):
    """A slip wall is a mirror plane: a disk centred on it is sampled as its half inside (the mass of
    a half disk, to the lattice's resolution), and the same disk across any other wall is refused."""
    from jaxmpm.model.scene import Boundary, Sphere

    disk = Phase("disk", "m", Sphere((0.0, 0.5), 0.3), ppc=4)
    make = lambda: _scene(phases=(disk,), boundary=Boundary(faces=(("x_lo", kind),)))
    if kind != "slip":
        with pytest.raises(ValueError, match=r"phase\.disk\.geometry .* inside the grid: axis x in \[0\.0, 1\.0\]"):
            make()
        return
    scene = make()
    s0 = jaxmpm.init_state(scene, jaxmpm.default_params(scene))
    assert float(jnp.min(s0.x[:, 0])) > 0.0
    half = 0.5 * np.pi * 0.3**2 * 1000.0  # kg per m of depth
    assert abs(float(jnp.sum(s0.mass)) / half - 1) < 0.02
    with pytest.raises(ValueError, match=r"axis x in \[-1\.0, 1\.0\]"):  # a mirror plane, not a free pass
        _scene(phases=(Phase("disk", "m", Sphere((-0.5, 0.5), 0.6)),), boundary=Boundary(faces=(("x_lo", "slip"),)))


def test_bspline_particle_in_the_last_half_cell():
    with pytest.raises(ValueError, match=r"phase\.block\.geometry: particle .* outside the grid's usable region"):
        _scene(phases=(Phase("block", "m", Box((0.0, 0.2), (0.5, 0.6))),), shape="bspline2")


@pytest.mark.parametrize("cfl", [0.0, -0.1, 1.5])
def test_cfl_outside_range(cfl):
    with pytest.raises(ValueError, match=r"cfl = .* allowed \(0, 1\]"):
        _scene(cfl=cfl)
    scene = _scene()
    params = dataclasses.replace(jaxmpm.default_params(scene), cfl=jaxmpm.default_params(scene).cfl * 0 + cfl)
    with pytest.raises(ValueError, match=r"params\.cfl = .* allowed \(0, 1\]"):
        jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, jaxmpm.default_params(scene)), t_end=1e-3)


def test_dt_above_cfl_limit_says_the_limit():
    scene = _scene()
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    limit = 0.3 * 0.1 / (1e6 * (1 - 0.3) / ((1 + 0.3) * (1 - 0.6)) / 1000.0) ** 0.5
    with pytest.raises(ValueError, match=rf"dt = .* above the CFL limit: allowed \(0, {limit:.6g}\] s"):
        jaxmpm.simulate(scene, params, state, t_end=1e-2, dt=2 * limit)
    jaxmpm.simulate(scene, params, state, t_end=2 * limit, dt=0.99 * limit, progress=False)  # below: runs


def test_unknown_material_key_lists_known_ones():
    with pytest.raises(
        ValueError,
        match=r"phase\.block\.material = 'unobtainium' is an unknown material key: known keys are \[.*'al2024'.*'m'.*\]",
    ):
        _scene(phases=(Phase("block", "unobtainium", Box((0.2, 0.2), (0.6, 0.6))),))


SCENE_TOML = """
name = "t"
[grid]
cells = [10, 10]
h = 0.1
[materials.m]
model = "linear_elastic"
rho0 = 1000.0
E = 1e6
nu = 0.3
[[phase]]
name = "block"
material = "m"
geometry = { type = "box", lo = [0.2, 0.2], hi = [0.6, 0.6] }
"""


def test_scene_file_round_trip_and_valid_file():
    scene = jaxmpm.io.scenefile.scene_from_toml(SCENE_TOML)
    assert jaxmpm.io.scenefile.scene_from_toml(jaxmpm.scene_to_toml(scene)) == scene


@pytest.mark.parametrize(
    "text,match",
    [
        (
            SCENE_TOML.replace("h = 0.1", "h = 0.1\nspacing = 2"),
            r"grid\.spacing is an unknown key: allowed keys are \['cells', 'h', 'origin'\]",
        ),
        (SCENE_TOML + "\nfoo = 1", r"phase\[0\]\.foo is an unknown key"),
        ("colour = 'red'\n" + SCENE_TOML, r"colour is an unknown key: allowed top-level keys"),
        (
            SCENE_TOML.replace("nu = 0.3", "nu = 0.3\nyield = 3e6"),
            r"materials\.m\.yield is not a constant of model 'linear_elastic'",
        ),
    ],
)
def test_unknown_toml_key(text, match):
    with pytest.raises(ValueError, match=match):
        jaxmpm.io.scenefile.scene_from_toml(text)


def test_malformed_toml_names_the_line(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(SCENE_TOML.replace("h = 0.1", "h = = 0.1"))
    with pytest.raises(ValueError, match=r"bad\.toml: malformed TOML: .*line 5"):
        jaxmpm.load_scene(str(path))


@pytest.mark.parametrize(
    "old,new,match",
    [
        ("cells = [10, 10]", 'cells = "ten"', r"grid\.cells = 'ten' is invalid: allowed a list of 1 to 3 integers"),
        ("h = 0.1", "h = -0.1", r"grid\.h = -0\.1 is invalid: allowed > 0 m"),
        ('material = "m"', "material = 3", r"phase\.block\.material = 3 is invalid"),
        ('type = "box"', 'type = "cone"', r"phase\.block\.geometry\.type = 'cone' is invalid: allowed box \| sphere"),
        ('name = "block"', 'name = "a b"', r"phase\.name = 'a b' is invalid"),
    ],
)
def test_wrong_types_and_values_in_scene_file(old, new, match):
    with pytest.raises(ValueError, match=match):
        jaxmpm.io.scenefile.scene_from_toml(SCENE_TOML.replace(old, new))


def test_particle_leaving_the_grid_stops_the_run_with_a_message():
    scene = _scene(phases=(Phase("block", "m", Box((0.6, 0.4), (0.8, 0.6)), velocity=(40.0, 0.0)),), t_end=0.02)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    with pytest.raises(
        FloatingPointError, match=r"particle \d+ of phase 'block' is outside the grid at t = .* allowed"
    ):
        jaxmpm.simulate(scene, params, state, progress=False)


def test_fixed_dt_that_becomes_unstable_stops_the_run():
    scene = _scene(t_end=0.05)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    limit = jaxmpm.cfl_limit(scene, params, state) * 0.3
    # a dt just under the limit at rest; the pre-compressed block then expands and speeds up
    stressed = dataclasses.replace(state, stress=state.stress.at[:].set(-2e6 * jnp.eye(2)))
    with pytest.raises(FloatingPointError, match=r"fixed dt = .* exceeds the CFL limit"):
        jaxmpm.simulate(scene, params, stressed, dt=0.999 * limit, progress=False)


def test_debug_mode_names_the_step_where_a_particle_leaves_the_grid():
    """simulate(..., debug=True) runs the chunks under checkify and stops at the step itself."""
    scene = _scene(phases=(Phase("block", "m", Box((0.6, 0.4), (0.8, 0.6)), velocity=(40.0, 0.0)),), t_end=0.02)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    with pytest.raises(
        FloatingPointError, match=r"checkify: step \d+ of the chunk \(t = .* s\): a particle left the grid"
    ):
        jaxmpm.simulate(scene, params, state, progress=False, debug=True)


def test_debug_mode_names_the_first_step_with_a_non_finite_field():
    scene = _scene(t_end=0.01)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    bad = dataclasses.replace(state, stress=state.stress.at[3].set(1e300))  # overflows: inf - inf
    with pytest.raises(
        FloatingPointError, match=r"checkify: step 0 of the chunk \(t = 1e-06 s\): a particle field is not finite"
    ):
        jaxmpm.simulate(scene, params, bad, progress=False, debug=True, dt=1e-6)


def test_debug_mode_gives_the_same_run():
    scene = _scene(phases=(Phase("block", "m", Box((0.2, 0.4), (0.4, 0.6)), velocity=(10.0, 0.0)),), t_end=0.005)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    a, _ = jaxmpm.simulate(scene, params, state, progress=False)
    b, _ = jaxmpm.simulate(scene, params, state, progress=False, debug=True)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_fragmentation_option_round_trips_and_bad_values_are_named():
    scene = dataclasses.replace(jaxmpm.io.scenefile.scene_from_toml(SCENE_TOML), c_h=0.1, fragmentation="plastic")
    assert jaxmpm.io.scenefile.scene_from_toml(jaxmpm.scene_to_toml(scene)) == scene
    with pytest.raises(
        ValueError, match=r"effects\.fragmentation = 'all' is invalid: allowed 'failed' \| 'plastic' \| 'tensile'"
    ):
        dataclasses.replace(scene, fragmentation="all")
    with pytest.raises(ValueError, match=r"effects\.fragmentation = 3 is invalid"):
        jaxmpm.io.scenefile.scene_from_toml(SCENE_TOML + "\n[effects]\nc_h = 0.1\nfragmentation = 3\n")


def test_difference_geometry_samples_around_the_hole_round_trips_and_names_bad_parts():
    """A fluid around a body: the base's particles outside the holes; the TOML text gives the scene
    back; a bad part is named with its path."""
    from jaxmpm.model.scene import Difference, Sphere
    from jaxmpm.model.sampling import sample_phase

    hole = Sphere((0.5, 0.5), 0.2)
    around = Difference(Box((0.0, 0.0), (1.0, 1.0)), (hole, Box((0.0, 0.0), (0.2, 0.2))))
    scene = _scene(phases=(Phase("body", "m", hole), Phase("fluid", "m", around, field=1)))
    body, fluid = (sample_phase(scene.grid, p) for p in scene.phases)
    full = sample_phase(scene.grid, Phase("all", "m", Box((0.0, 0.0), (1.0, 1.0))))
    assert len(body) > 0 and len(fluid) + len(body) + 16 == len(full)  # the corner box holds 4 x 4 points
    assert not np.any(np.sum((fluid - 0.5) ** 2, 1) < 0.2**2)
    assert jaxmpm.io.scenefile.scene_from_toml(jaxmpm.scene_to_toml(scene)) == scene
    text = 'type = "cone"'.join(jaxmpm.scene_to_toml(scene).rsplit('type = "sphere"', 1))  # the hole's
    with pytest.raises(
        ValueError,
        match=r"phase\.fluid\.geometry\.minus\[0\]\.type = 'cone' is invalid: allowed box \| sphere \| difference",
    ):
        jaxmpm.io.scenefile.scene_from_toml(text)
    with pytest.raises(ValueError, match=r"geometry\.base = .* allowed a Box or Sphere"):
        Difference("box", ())
