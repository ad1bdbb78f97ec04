"""Patch test (PHYSICS 2.2, rules R1-R3): a linear nodal velocity field gives the exact velocity
gradient at every particle, including particles next to a fixed wall and at a free surface."""
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.scene import Boundary, Box, Grid, Phase, Scene
from jaxmpm.shapes import stencil
from jaxmpm.step import Layout, _apply_bc, particle_velocity_gradient
from jaxmpm.transfer import scatter_weighted


def _scene(dim, shape, wall):
    # material from the grid's lower corner (next to the wall at x = 0) to an interior free surface
    # that cuts cells off-centre; grid extends beyond it.
    cells = (12, 9, 7)[:dim]
    hi = (0.83, 0.47, 0.55)[:dim]
    faces = (("x_lo", "fixed"),) if wall else ()
    lo = (0.0,) + (0.13, 0.21)[:dim - 1] if wall else (0.17, 0.13, 0.21)[:dim]
    mat = jaxmpm.Material.make("m", "linear_elastic", rho0=1000.0, E=1e6, nu=0.25)
    return Scene(grid=Grid(cells=cells, h=0.1), phases=(Phase("block", "m", Box(lo, hi), ppc=2),),
                 materials=(mat,), shape=shape, boundary=Boundary(faces=faces))


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
    if wall:   # a field that a fixed wall at x = 0 admits: v = A[:, 0] x_0
        A[:, 1:] = 0.0
    b = np.zeros(dim) if wall else rng.normal(size=dim)
    xn = _nodal_positions(scene.grid)
    lay = Layout.of(scene)
    v = jnp.asarray(xn @ A.T + b)[None]                       # (1, n_nodes, d)
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
