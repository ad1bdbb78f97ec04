"""Patch test (PHYSICS 2.2, rules R1-R3): a linear nodal velocity field gives the exact velocity
gradient at every particle, including particles next to a fixed wall and at a free surface."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.model.scene import Boundary, Box, Grid, Phase, Scene
from jaxmpm.numerics.shapes import stencil
from jaxmpm.stages.layout import Layout
from jaxmpm.stages.grid_to_particle import particle_velocity_gradient
from jaxmpm.stages.layout import apply_walls as _apply_bc
from jaxmpm.numerics.transfer import scatter_weighted


def _scene(dim, shape, wall):
    # material from the grid's lower corner (next to the wall at x = 0) to an interior free surface
    # that cuts cells off-centre; grid extends beyond it.
    cells = (12, 9, 7)[:dim]
    hi = (0.83, 0.47, 0.55)[:dim]
    faces = (("x_lo", "fixed"),) if wall else ()
    lo = (0.0,) + (0.13, 0.21)[: dim - 1] if wall else (0.17, 0.13, 0.21)[:dim]
    mat = jaxmpm.Material.make("m", "linear_elastic", rho0=1000.0, E=1e6, nu=0.25)
    return Scene(
        grid=Grid(cells=cells, h=0.1),
        phases=(Phase("block", "m", Box(lo, hi), ppc=2),),
        materials=(mat,),
        shape=shape,
        boundary=Boundary(faces=faces),
    )


def _nodal_positions(grid):
    axes = [grid.origin[k] + grid.h * np.arange(n) for k, n in enumerate(grid.nodes)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, grid.dim)


@pytest.mark.parametrize("dim", [1, 2, 3])
@pytest.mark.parametrize("shape", ["ddmp", "linear"])
@pytest.mark.parametrize("wall", [False, True], ids=["free_surface", "fixed_wall"])
def test_linear_field_gives_exact_gradient(dim, shape, wall):
    scene = _scene(dim, shape, wall)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    rng = np.random.default_rng(dim)
    A = rng.normal(size=(dim, dim))
    if wall:  # a field that a fixed wall at x = 0 admits: v = A[:, 0] x_0
        A[:, 1:] = 0.0
    b = np.zeros(dim) if wall else rng.normal(size=dim)
    xn = _nodal_positions(scene.grid)
    lay = Layout.of(scene)
    v = jnp.asarray(xn @ A.T + b)[None]  # (1, n_nodes, d)
    v = _apply_bc(lay, v)
    st = stencil(scene, state.x)
    vol = scatter_weighted(st, None, state.volume[:, None], 1, lay.n_nodes)[..., 0] if shape == "ddmp" else None
    L = particle_velocity_gradient(lay, st, v, vol, volume=state.volume)
    np.testing.assert_allclose(np.asarray(L), np.broadcast_to(A, L.shape), rtol=0, atol=1e-12)
    # the patch includes particles in the cells at the wall / free surface
    x = np.asarray(state.x)
    h = scene.grid.h
    assert (x[:, 0] < h).any() if wall else (x[:, 0] < 0.2).any()
    assert (x[:, 0] > 0.8).any()


@pytest.mark.parametrize("shape", ["ddmp", "linear"])
@pytest.mark.parametrize("on_axis", [True, False], ids=["from_the_axis", "annulus"])
def test_axisymmetric_linear_field_gives_exact_gradient_and_hoop_rate(shape, on_axis):
    """v_r = a r, v_z = c r + b z + e (the linear fields the axis admits): L_rr = a, L_zr = c,
    L_zz = b and the hoop rate L_thth = v_r / r = a at every particle, also at the axis and at the
    free surfaces; the volumes per radian are r dr dz."""
    mat = jaxmpm.Material.make("m", "hypoelastic", rho0=1000.0, E=1e6, nu=0.25)
    lo = (0.0, 0.13) if on_axis else (0.23, 0.13)
    scene = Scene(
        grid=Grid(cells=(10, 10), h=0.1),
        phases=(Phase("block", "m", Box(lo, (0.77, 0.81)), ppc=2),),
        materials=(mat,),
        shape=shape,
        axisymmetric=True,
    )
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    np.testing.assert_allclose(np.asarray(state.volume), np.asarray(state.x[:, 0]) * 0.05**2, rtol=1e-12)
    assert state.stress.shape[1:] == (3, 3) and state.F.shape[1:] == (3, 3)
    a, b, c, e = 0.7, -1.3, 0.4, 2.0
    xn = _nodal_positions(scene.grid)
    lay = Layout.of(scene)
    v = jnp.asarray(np.stack([a * xn[:, 0], c * xn[:, 0] + b * xn[:, 1] + e], -1))[None]
    v = _apply_bc(lay, v)
    st = stencil(scene, state.x)
    vol = scatter_weighted(st, None, state.volume[:, None], 1, lay.n_nodes)[..., 0] if shape == "ddmp" else None
    L = particle_velocity_gradient(lay, st, v, vol, volume=state.volume, radius=state.x[:, 0])
    expected = np.array([[a, 0.0, 0.0], [c, b, 0.0], [0.0, 0.0, a]])
    np.testing.assert_allclose(np.asarray(L), np.broadcast_to(expected, L.shape), rtol=0, atol=1e-12)
