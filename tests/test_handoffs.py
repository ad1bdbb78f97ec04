"""The stages hand over named tuples (jaxmpm.stages.nodal.NodalSums, GridUpdate,
jaxmpm.stages.constitutive.ConstitutiveUpdate) whose fields are set exactly where the scene uses them."""

import dataclasses

import jax
import jax.numpy as jnp
import pytest

import jaxmpm
from jaxmpm.numerics.shapes import ddmp_beta, stencil
from jaxmpm.stages.constitutive import ConstitutiveUpdate, constitutive
from jaxmpm.stages.grid_update import grid_acceleration
from jaxmpm.stages.layout import Layout, mass_floor
from jaxmpm.stages.nodal import GridUpdate, NodalSums
from jaxmpm.stages.particle_to_grid import particle_to_grid


def stages_2_and_3(scene):
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    lay = Layout.of(scene)
    st = stencil(scene, state.x)
    beta = ddmp_beta(st.xi) if scene.shape == "ddmp" else None
    sums = particle_to_grid(lay, params, st, state, beta)
    grid = grid_acceleration(lay, params, state, st, beta, sums, None, jnp.asarray(1e-7), mass_floor(lay, state))
    return lay, params, state, sums, grid


def set_fields(t):
    return {k for k, v in t._asdict().items() if v is not None}


def test_one_field_without_ddmp_scatters_mass_momentum_and_force_only():
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25).replace(shape="linear")
    lay, params, state, sums, grid = stages_2_and_3(scene)
    assert isinstance(sums, NodalSums) and set_fields(sums) == {"mass", "momentum", "force"}
    n, d = lay.n_nodes, lay.dim
    assert sums.mass.shape == (1, n, 1) and sums.momentum.shape == (1, n, d) and sums.force.shape == (1, n, d)
    assert float(jnp.sum(sums.mass)) == float(jnp.sum(state.mass))  # the stencil weights sum to 1
    assert isinstance(grid, GridUpdate) and set_fields(grid) == {"v", "a"}


def test_two_fields_with_interface_forces_scatter_what_the_coupling_reads():
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2)
    lay, params, state, sums, grid = stages_2_and_3(scene)
    assert {"mass", "momentum", "force", "stress_share", "volume", "compressible_volume"} <= set_fields(sums)
    assert sums.volume.shape == (2, lay.n_nodes, 1) and sums.stress_share.shape == (2, lay.n_nodes, lay.dim**2)
    assert grid.ddmp is not None


def test_the_constitutive_update_names_state_fields():
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    L = jnp.zeros_like(state.F)
    new = constitutive(Layout.of(scene), params, state, L, jnp.asarray(1e-7))
    assert isinstance(new, ConstitutiveUpdate)
    assert set(new._fields) <= {f.name for f in dataclasses.fields(state)}
    assert jnp.array_equal(new.volume, state.volume)  # no velocity gradient: no change of volume


def test_the_hand_offs_answer_the_keys_of_the_dicts_they_replace():
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25)
    lay, params, state, sums, grid = stages_2_and_3(scene)
    assert sums["m"] is sums.mass and sums["mass"] is sums.mass and sums["f"] is sums.force
    assert "vol" in sums and "pm" not in sums and sums[0] is sums.mass
    new = constitutive(lay, params, state, jnp.zeros_like(state.F), jnp.asarray(1e-7))
    assert new["eps_ps"] is new.eps_ps and new[0] is new.F


@pytest.mark.parametrize(
    "name, options",
    [("elastic_impact", dict(resolution=0.25)), ("debris_cloud", dict(resolution=0.75, fields=2, drag_heating=True))],
)
def test_a_step_mixes_no_dtypes_implicitly(name, options):
    """Under strict dtype promotion (no int32 with int64, no bool with a float): the step casts."""
    scene = jaxmpm.load_scene(name, **options)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.initial_state(scene, params)
    with jax.numpy_dtype_promotion("strict"):
        new = jax.jit(jaxmpm.make_step(scene))(params, state)
    assert float(new.t) > 0
