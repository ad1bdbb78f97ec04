"""The per-field grid operators on blocks of cells (Scene.window) equal the whole grid's: the DDMP
operators on each field's block (values, gradients with respect to the nodal inputs and to the
nodal volume, 1D/2D/3D and axisymmetric, blocks that hold their field and blocks that do not,
which fall back to the whole grid), the exchange on the block of shared nodes, and a whole run
of a three-field impact (values; a gradient in the slow set)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.numerics import ddmp
from jaxmpm.model.geometry import Grid
from jaxmpm.model.scene import Box, Phase, Scene
from jaxmpm.io.scenefile import scene_from_toml, scene_to_toml

jax.config.update("jax_enable_x64", True)


def fields_in_blocks(rng, grid, K, blocks, axisymmetric):
    """Nodal volumes (K, *nodes), random everywhere (what lies outside a field's cells must not
    matter), and cell volumes (K, *cells) that are nonzero only in field k's block of cells
    blocks[k] = (lo, hi) (per axis, hi exclusive), with a fifth of those cells empty."""
    support = ddmp.node_support(grid, axisymmetric)
    nodal_volume = rng.uniform(0, 1.2, (K,) + grid.nodes) * support
    cell_volume = np.zeros((K,) + grid.cells)
    for k, (lo, hi) in enumerate(blocks):
        idx = (k,) + tuple(slice(a, b) for a, b in zip(lo, hi))
        cell_volume[idx] = rng.uniform(0.2, 1, cell_volume[idx].shape) * grid.h**grid.dim * 0.3
    cell_volume[rng.uniform(size=cell_volume.shape) < 0.2] = 0.0
    return jnp.asarray(nodal_volume), jnp.asarray(cell_volume)


CASES = {  # dim, axisymmetric, grid cells, the fields' occupied blocks, window
    "1D": (1, False, (12,), [((2,), (5,)), ((6,), (9,))], (4,)),
    "2D": (2, False, (10, 9), [((1, 2), (4, 5)), ((5, 0), (9, 3)), ((6, 6), (10, 9))], (4, 3)),
    "2D at the grid's edges": (2, False, (10, 9), [((0, 0), (3, 2)), ((7, 6), (10, 9))], (4, 3)),
    "3D": (3, False, (6, 5, 7), [((0, 1, 2), (2, 3, 5)), ((3, 2, 0), (6, 5, 3))], (3, 3, 3)),
    "axisymmetric": (2, True, (8, 9), [((0, 1), (3, 4)), ((4, 5), (7, 8))], (3, 4)),
    "a field outgrows its block": (2, False, (10, 9), [((1, 2), (4, 5)), ((2, 0), (9, 3))], (4, 3)),
}


# 2D, axisymmetric (its own radius slices) and a field outgrowing its block in the default run;
# 1D, 3D and the grid's edges (the 2D code with another geometry) in the slow set, to keep the
# default run under 15 minutes
SLOW_CASES = ("2D at the grid's edges", "3D", "1D")


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in SLOW_CASES else c for c in CASES])
def test_operators_on_blocks_equal_the_whole_grid(case):
    dim, axisymmetric, cells, blocks, window = CASES[case]
    rng = np.random.default_rng(len(case))
    grid = Grid(cells=cells, h=0.1, origin=(0.0, 0.2, -0.1)[:dim])
    K = len(blocks)
    nv, cv = fields_in_blocks(rng, grid, K, blocks, axisymmetric)
    fits = bool(jnp.all(ddmp.window_origin(cv, window)[1]))
    assert fits == (case != "a field outgrows its block")
    shv = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (dim, dim)))
    v = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (dim,)))
    p = jnp.asarray(rng.normal(size=grid.nodes))
    shp = jnp.asarray(rng.normal(size=(K,) + grid.nodes))

    def outputs(nv, shv, v, p, shp, window):
        dg = ddmp.build(grid, nv, cv, axisymmetric, window)
        return (
            ddmp.nodal_stress_force(grid, dg, shv),
            ddmp.nodal_velocity_gradient(grid, dg, v),
            ddmp.nodal_interface_force(grid, dg, shp, p),
            ddmp.nodal_interface_force(grid, dg, None, p),
        )

    args = (nv, shv, v, p, shp)
    weights = [jnp.asarray(rng.normal(size=o.shape)) for o in jax.eval_shape(lambda *a: outputs(*a, None), *args)]

    def loss(window):
        return lambda *a: sum(jnp.sum(w * jnp.sin(o)) for w, o in zip(weights, outputs(*a, window)))

    def both(*a):  # one program for the whole grid and the blocks, values and gradients
        grads = [jax.grad(loss(w_), argnums=tuple(range(5)))(*a) for w_ in (None, window)]
        return outputs(*a, None), outputs(*a, window), grads

    whole, blocks_, (g_whole, g_blocks) = jax.jit(both)(*args)
    for a, b in zip(whole, blocks_):
        assert float(jnp.max(jnp.abs(a))) > 0
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(a))))
    for a, b in zip(g_whole, g_blocks):  # the nodal volume's gradient reaches the operators through A and V
        np.testing.assert_allclose(b, a, rtol=1e-11, atol=1e-11 * float(jnp.max(jnp.abs(a))))


def test_a_vmapped_batch_with_and_without_fitting_fields_equals_the_whole_grid():
    """Under vmap the conditionals become selects: a batch of two members, one whose fields fit
    their blocks and one whose field does not, gives each member's whole-grid values."""
    _, _, cells, blocks_in, window = CASES["2D"]
    blocks_out = CASES["a field outgrows its block"][3] + [CASES["2D"][3][2]]
    grid = Grid(cells=cells, h=0.1, origin=(0.0, 0.2))
    rng = np.random.default_rng(5)
    members = [fields_in_blocks(rng, grid, 3, b, False) for b in (blocks_in, blocks_out)]
    v = jnp.asarray(rng.normal(size=(2, 3) + grid.nodes + (2,)))
    p = jnp.asarray(rng.normal(size=(2,) + grid.nodes))

    def ops(nv, cv, v, p, window):
        dg = ddmp.build(grid, nv, cv, False, window)
        return ddmp.nodal_velocity_gradient(grid, dg, v), ddmp.nodal_interface_force(grid, dg, None, p)

    nv, cv = (jnp.stack(a) for a in zip(*members))
    assert [bool(jnp.all(ddmp.window_origin(c, window)[1])) for c in cv] == [True, False]
    batched = jax.jit(jax.vmap(lambda *a: ops(*a, window)))(nv, cv, v, p)
    for i in range(2):
        for a, b in zip(jax.jit(lambda *args: ops(*args, None))(nv[i], cv[i], v[i], p[i]), batched):
            np.testing.assert_allclose(b[i], a, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(a))))


def test_window_origin_follows_the_field_and_says_when_it_does_not_fit():
    cv = np.zeros((3, 10, 8))
    cv[0, 2:5, 3:6] = 1.0  # fits a 4 x 3 block starting at its first cell
    cv[1, 7:10, 6:8] = 1.0  # at the grid's far corner: the block is moved back inside the grid
    cv[2, 0:6, 0:2] = 1.0  # 6 cells along x: does not fit 4
    origin, fits = ddmp.window_origin(jnp.asarray(cv), (4, 3))
    np.testing.assert_array_equal(origin, [[2, 3], [6, 5], [0, 0]])
    np.testing.assert_array_equal(fits, [True, True, False])
    origin, fits = ddmp.window_origin(jnp.zeros((1, 10, 8)), (4, 3))  # an empty field fits anywhere
    assert bool(fits[0])


def impact(window=None, n=32):
    """Three aluminium blocks as three fields on an n^2 grid: a striker at 500 m/s onto a plate on a
    backing block (benchmarks/multifield_cost.py's scene, coarser)."""
    al = jaxmpm.Material.make("al", "linear_elastic", rho0=2700.0, E=70e9, nu=0.33)
    phases = (
        Phase("striker", "al", Box((0.40, 0.62), (0.60, 0.80)), velocity=(0.0, -500.0), field=0),
        Phase("plate", "al", Box((0.20, 0.50), (0.80, 0.60)), field=1),
        Phase("backing", "al", Box((0.20, 0.20), (0.80, 0.48)), field=2),
    )
    return Scene(grid=Grid(cells=(n, n), h=1.0 / n), materials=(al,), phases=phases, drag=1e3, window=window)


@pytest.mark.parametrize(
    "shared_block,fits",
    [(((10, 12), (20, 18)), True), pytest.param(((2, 12), (30, 18)), False, marks=pytest.mark.slow)],
)
def test_exchange_on_the_shared_block_equals_the_whole_grid(shared_block, fits):
    """Random nodal masses, volumes and velocities of three fields: each field has volume on its own
    region, and two or more share the nodes of `shared_block` (lo, hi per axis); the window
    (21, 10) holds that block in the first case, not in the second (the whole grid)."""
    from jaxmpm.stages.multifield import exchange_force
    from jaxmpm.stages.layout import Layout

    scene = impact((21, 10))
    lay, params = Layout.of(scene), jaxmpm.default_params(scene)
    rng = np.random.default_rng(3)
    nodes = scene.grid.nodes
    present = np.zeros((3,) + nodes, bool)
    present[0, 2:12, 20:30] = True
    present[1, 15:30, 3:10] = True
    present[2, 25:33, 25:33] = True
    (x0, y0), (x1, y1) = shared_block
    present[0, x0:x1, y0:y1] = present[1, x0:x1, y0:y1] = True
    present[2, x0:x1, y0 : y0 + 2] = True
    vol = jnp.asarray(np.where(present, rng.uniform(0.1, 1, present.shape), 0.0).reshape(3, -1) * scene.grid.h**2)
    m = vol * 2700.0
    v = jnp.asarray(rng.normal(size=(3, vol.shape[1], 2)) * 50.0)
    dt = jnp.asarray(2e-6)
    whole = Layout.of(dataclasses.replace(scene, window=None))

    def force(lay, m, vol, v):
        return exchange_force(lay, params, m, vol, v, dt, 1e-20)

    w = jnp.asarray(rng.normal(size=v.shape)) / (2700.0 * float(jnp.max(vol)) * 1e6)  # ~ 1 / F

    def both(*a):  # one program: values and gradients, whole grid and blocks
        return [
            (force(l, *a), jax.grad(lambda *a: jnp.sum(w * force(l, *a) ** 2), argnums=(0, 1, 2))(*a))
            for l in (whole, lay)
        ]

    (F0, g0), (F1, g1) = jax.jit(both)(m, vol, v)
    assert float(jnp.max(jnp.abs(F0))) > 0
    np.testing.assert_allclose(jnp.sum(F0, 0), 0.0, atol=1e-12 * float(jnp.max(jnp.abs(F0))))
    np.testing.assert_allclose(F1, F0, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(F0))))
    for a, b in zip(g0, g1):
        np.testing.assert_allclose(b, a, rtol=1e-11, atol=1e-11 * float(jnp.max(jnp.abs(a))))
    shared = (jnp.sum(vol > 0, 0) >= 2).reshape((1,) + nodes)
    assert bool(ddmp.window_origin(shared, (22, 11))[1][0]) == fits


def impact_run(window, gradient):
    """The final state of 60 steps (through the contact), or with gradient=True the momentum of
    what lies above y = 0.5 m, its derivative with respect to the drag coefficient and the state."""
    scene = impact(window)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    step = jaxmpm.make_step(scene)

    def loss(cd):
        p = dataclasses.replace(params, drag=cd)
        s = jax.lax.scan(lambda c, _: (step(p, c), None), s0, None, length=60)[0]
        return jnp.sum(s.mass * s.v[:, 1] * (s.x[:, 1] > 0.5).astype(s.mass.dtype)), s

    if gradient:
        (l, s), g = jaxmpm.jit(jax.value_and_grad(loss, has_aux=True))(params.drag)
        return s, (l, g)
    return jaxmpm.jit(lambda cd: loss(cd)[1])(params.drag), None


def assert_same_run(ref, s, what):
    for name in ("x", "v", "stress", "volume"):
        a, b = getattr(ref, name), getattr(s, name)
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12 * float(jnp.max(jnp.abs(a))), err_msg=f"{what} {name}")


@pytest.mark.slow
def test_a_three_field_impact_on_blocks_runs_as_on_the_whole_grid():
    """Blocks that hold every field (the striker's block follows it down) and blocks too small for
    the backing field (the whole grid every step): the run of the whole grid to round-off."""
    ref, _ = impact_run(None, False)
    assert float(jnp.max(jnp.abs(ref.stress))) > 1e8  # the blocks are in contact
    for window in ((21, 10), (8, 8)):
        assert_same_run(ref, impact_run(window, False)[0], window)


@pytest.mark.slow
def test_a_three_field_impact_on_blocks_has_the_whole_grids_gradient():
    """d(momentum above y = 0.5 m) / d C_d through the 60 steps, on blocks and on the whole grid."""
    ref, (l0, g0) = impact_run(None, True)
    s, (l, g) = impact_run((21, 10), True)
    assert float(g0) != 0.0
    assert_same_run(ref, s, "gradient run")
    np.testing.assert_allclose([l, g], [l0, g0], rtol=1e-9)


@pytest.mark.parametrize(
    "window,why",
    [
        ((0, 4), "1..grid.cells"),
        ((4,), "2 integers"),
        ((40, 4), "1..grid.cells"),
        ((4.0, 4), "integers"),
        ("4", "integers"),
    ],
)
def test_bad_windows_are_named(window, why):
    with pytest.raises(ValueError, match="window") as e:
        impact(window)
    assert why.split()[0] in str(e.value)


def test_window_needs_operators_to_put_on_blocks_and_survives_the_scene_file():
    rock = jaxmpm.Material.make("rock", "linear_elastic", rho0=2000.0, E=1e9, nu=0.25)
    with pytest.raises(ValueError, match="window.*DDMP operators"):
        Scene(
            grid=Grid(cells=(10, 10), h=0.1),
            materials=(rock,),
            shape="linear",
            phases=(Phase("a", "rock", Box((0.2, 0.2), (0.5, 0.5))),),
            window=(4, 4),
        )
    scene = impact((21, 10))
    assert scene_from_toml(scene_to_toml(scene)) == scene
    assert "window = [21, 10]" in scene_to_toml(scene)
