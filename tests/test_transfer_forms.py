"""The optimised transfer and DDMP operators equal their straightforward forms (einsum, sums of
shifted copies) on random data, values and gradients: particles anywhere in their cells, on cell
faces and on nodes, cells without material (zero weights), 1D/2D/3D and axisymmetric."""

import jax
import jax.extend
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmpm.numerics import ddmp
from jaxmpm.numerics.compile import native_reductions_forms
from jaxmpm.model.geometry import Grid
from jaxmpm.numerics.shapes import bspline2_stencil, linear_stencil
from jaxmpm.numerics.shapes import stencil_offsets
from jaxmpm.numerics.transfer import (
    gather,
    gather_by_offset,
    offset_stencil,
    scatter,
    scatter_by_offset,
    scatter_by_window,
    stencil_apply,
    stencil_outer,
)

RTOL = 1e-12


def add_corners_shifted(c, dim):
    """Reference: per-cell corner values summed onto nodes as a sum of shifted, padded copies."""
    total = 0
    extra = c.ndim - 2 - dim
    for s, o in enumerate(stencil_offsets(dim, 2)):
        pad = [(0, 0)] + [(int(o[k]), 1 - int(o[k])) for k in range(dim)] + [(0, 0)] * extra
        total = total + jnp.pad(jnp.take(c, s, axis=1 + dim), pad)
    return total


def particles_on_faces(rng, grid, n):
    """Random positions, a third of them snapped to cell faces or nodes."""
    lo, hi = np.asarray(grid.origin), np.asarray(grid.hi)
    x = lo + rng.uniform(0, 1, (n, grid.dim)) * (hi - lo)
    snap = rng.uniform(size=(n, grid.dim)) < 0.33
    on = lo + np.round((x - lo) / grid.h) * grid.h
    return jnp.asarray(np.where(snap, on, x))


def random_ddmp_grid(rng, dim, K=2, axisymmetric=False):
    grid = Grid(cells=(3, 4, 2)[:dim], h=0.1, origin=(0.0, 0.2, -0.1)[:dim])
    support = ddmp.node_support(grid, axisymmetric)
    nodal_volume = jnp.asarray(rng.uniform(0, 1.2, (K,) + grid.nodes) * support)
    cell_volume = rng.uniform(0, 1, (K,) + grid.cells) * grid.h**dim * 0.1
    cell_volume[rng.uniform(size=cell_volume.shape) < 0.3] = 0.0  # empty cells
    return grid, ddmp.build(grid, nodal_volume, jnp.asarray(cell_volume), axisymmetric)


@pytest.mark.parametrize("form", ["cpu", "gpu"])
@pytest.mark.parametrize("dim", [1, 2, pytest.param(3, marks=pytest.mark.slow)])
def test_add_corners_equals_shifted_sums(dim, form):
    """Both forms of the corner sums (jaxmpm/forms.py: a loop over the corners, one fused sum),
    values, gradients and a batched second derivative."""
    from jaxmpm.numerics.forms import transfer_forms

    rng = np.random.default_rng(dim)
    cells = (3, 4, 2)[:dim]
    c = jnp.asarray(rng.normal(size=(2,) + cells + (2**dim, 3, 2)))
    w = jnp.asarray(rng.normal(size=(2,) + tuple(n + 1 for n in cells) + (3, 2)))
    loss = lambda add: lambda c: jnp.sum(w * jnp.sin(add(c, dim)))
    hvp = lambda add: jax.vmap(lambda t: jax.jvp(jax.grad(loss(add)), (c,), (t,))[1])(jnp.stack([c, c**2]))
    with transfer_forms(form):
        np.testing.assert_allclose(ddmp.add_corners(c, dim), add_corners_shifted(c, dim), rtol=RTOL, atol=1e-14)
        g1, h1 = jax.grad(loss(ddmp.add_corners))(c), hvp(ddmp.add_corners)
    g2, h2 = jax.grad(loss(add_corners_shifted))(c), hvp(add_corners_shifted)
    np.testing.assert_allclose(g1, g2, rtol=RTOL, atol=1e-14)
    np.testing.assert_allclose(h1, h2, rtol=1e-11, atol=1e-13)
    assert float(jnp.abs(h2).max()) > 0


@pytest.mark.parametrize("native", [False, True])
@pytest.mark.parametrize(
    "dim,axisymmetric", [(1, False), (2, False), pytest.param(3, False, marks=pytest.mark.slow), (2, True)]
)
def test_ddmp_operators_equal_their_einsum_forms(dim, axisymmetric, native):
    """Both forms of the corner contractions (compile.native_reductions: reductions under
    jaxmpm.jit, unrolled sums elsewhere)."""
    with native_reductions_forms(native):
        check_ddmp_operators(dim, axisymmetric)


def check_ddmp_operators(dim, axisymmetric):
    rng = np.random.default_rng(10 + dim)
    grid, dg = random_ddmp_grid(rng, dim, axisymmetric=axisymmetric)
    K = dg.V.shape[0]
    # the cell integrals of build (R3) against the einsum of the theta corners and the tensors
    T0, Tg = ddmp.cell_tensors(dim, grid.h)
    tc = ddmp.corners(jnp.asarray(rng.uniform(size=(K,) + grid.nodes)), dim)
    integrate = ddmp._cell_integrator(grid, tc.dtype, False)
    np.testing.assert_allclose(integrate(tc, Tg, None), jnp.einsum("...n,jnik->...jik", tc, Tg), rtol=RTOL)
    np.testing.assert_allclose(integrate(tc, T0, None), jnp.einsum("...n,jn->...j", tc, T0), rtol=RTOL)
    vmin = 1e-12 * grid.h**dim

    def force_ref(shv):
        sig = jnp.where(dg.V[..., None, None] > vmin, shv / jnp.where(dg.V > vmin, dg.V, 1.0)[..., None, None], 0.0)
        return add_corners_shifted(-jnp.einsum("...jab,...jib->...ia", ddmp.corners(sig, dim), dg.A), dim)

    def grad_ref(v):
        Lc = jnp.einsum("...ia,...jib->...jab", ddmp.corners(v, dim), dg.A)
        V = dg.V[..., None, None]
        return jnp.where(V > vmin, add_corners_shifted(Lc, dim) / jnp.where(V > vmin, V, 1.0), 0.0)

    def scalar_ref(p):
        return add_corners_shifted(jnp.einsum("...i,...nik->...nk", ddmp.corners(p[None], dim), dg.A), dim)

    shv = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (dim, dim)))
    v = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (dim,)))
    p = jnp.asarray(rng.normal(size=grid.nodes))
    shp = jnp.asarray(rng.normal(size=(K,) + grid.nodes))
    for fast, ref, arg in (
        (lambda a: ddmp.nodal_stress_force(grid, dg, a), force_ref, shv),
        (lambda a: ddmp.nodal_velocity_gradient(grid, dg, a), grad_ref, v),
        (
            lambda a: ddmp.nodal_interface_force(grid, dg, shp, a),  # E13: isotropic share and theta S grad p
            lambda a: force_ref(shp[..., None, None] * jnp.eye(dim)) - scalar_ref(a),
            p,
        ),
        (
            lambda a: ddmp.nodal_interface_force(grid, dg, a, p),
            lambda a: force_ref(a[..., None, None] * jnp.eye(dim)) - scalar_ref(p),
            shp,
        ),
        (lambda a: ddmp.nodal_interface_force(grid, dg, None, a), lambda a: -scalar_ref(a), p),
    ):
        np.testing.assert_allclose(jax.jit(fast)(arg), jax.jit(ref)(arg), rtol=1e-11, atol=1e-12)
        w = jnp.asarray(rng.normal(size=jax.eval_shape(fast, arg).shape))
        np.testing.assert_allclose(
            jax.jit(jax.grad(lambda a: jnp.sum(w * fast(a))))(arg),
            jax.jit(jax.grad(lambda a: jnp.sum(w * ref(a))))(arg),
            rtol=1e-11,
            atol=1e-12,
        )
        t = jnp.asarray(rng.normal(size=arg.shape))  # forward mode too
        np.testing.assert_allclose(
            jax.jit(lambda a, t: jax.jvp(fast, (a,), (t,))[1])(arg, t),
            jax.jit(lambda a, t: jax.jvp(ref, (a,), (t,))[1])(arg, t),
            rtol=1e-11,
            atol=1e-12,
        )


@pytest.mark.parametrize("native", [False, True])
def test_ddmp_operators_differentiate_through_their_cell_integrals(native):
    """The gradient with respect to the nodal volume, which reaches the operators through the
    cell integrals A of `build` (the second argument of the corner contractions)."""
    rng = np.random.default_rng(7)
    grid = Grid(cells=(3, 4), h=0.1, origin=(0.0, 0.2))
    K = 2
    nv0 = jnp.asarray(rng.uniform(0.2, 0.9, (K,) + grid.nodes) * ddmp.node_support(grid))
    cell_volume = jnp.asarray(rng.uniform(0.5, 1, (K,) + grid.cells) * grid.h**2 * 0.5)
    shv = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (2, 2)))
    v = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (2,)))
    w = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (2,)))

    def loss(nv, contract_force, contract_grad):
        dg = ddmp.build(grid, nv, cell_volume)
        f = ddmp.add_corners(-contract_force(ddmp.corners(shv, 2), dg.A), 2)
        Lc = ddmp.add_corners(contract_grad(ddmp.corners(v, 2), dg.A), 2)
        return jnp.sum(w * f) + jnp.sum(jnp.sin(Lc))

    with native_reductions_forms(native):
        fast = jax.jit(jax.grad(lambda nv: loss(nv, ddmp._force_contraction, ddmp._gradient_contraction)))(nv0)
    ref = jax.jit(
        jax.grad(
            lambda nv: loss(
                nv,
                lambda s, A: jnp.einsum("...jab,...jib->...ia", s, A),
                lambda c, A: jnp.einsum("...ia,...jib->...jab", c, A),
            )
        )
    )(nv0)
    np.testing.assert_allclose(fast, ref, rtol=1e-11, atol=1e-12)
    assert float(jnp.abs(ref).max()) > 0


def _eqns(jaxpr):
    """Every equation of a jaxpr, those of its sub-jaxprs (loops, conditionals, calls) included."""
    for e in jaxpr.eqns:
        yield e
        for v in e.params.values():
            for sub in v if isinstance(v, (list, tuple)) else (v,):
                if isinstance(sub, jax.extend.core.ClosedJaxpr):
                    yield from _eqns(sub.jaxpr)
                elif isinstance(sub, jax.extend.core.Jaxpr):
                    yield from _eqns(sub)


def test_contractions_inside_a_linearisation_keep_their_reduced_tangent():
    """The continuity form evaluates the interface forces (E13) inside `jax.vjp` and takes its
    transpose (E7); a gradient of the step differentiates that linearisation's value and transpose
    again. The contractions' value comes through the contraction itself, so the outer derivative
    takes the reduced tangent, whose reverse mode builds A's cotangent as a broadcast product, not
    the transpose of the unrolled sums: a padded copy of A per corner (the debris cloud's gradient
    spent 0.5 ms per step on those copies). Gradients against the einsum reference."""
    rng = np.random.default_rng(11)
    grid, dg = random_ddmp_grid(rng, 2)
    K = dg.V.shape[0]
    p = jnp.asarray(rng.normal(size=grid.nodes))
    shp = jnp.asarray(rng.normal(size=(K,) + grid.nodes))
    w = jnp.asarray(rng.normal(size=(K,) + grid.nodes + (2,)))

    def loss(A, p, contract_scalar, contract_isotropic):
        def forces(p):
            c = -contract_scalar(ddmp.corners(p[None], 2), A) - contract_isotropic(ddmp.corners(shp, 2), A)
            return ddmp.add_corners(c, 2)

        I, transpose = jax.vjp(forces, p)
        return jnp.sum(jnp.sin(I)) + jnp.sum(transpose(w)[0] ** 2)

    fast = lambda A, p: loss(A, p, ddmp._scalar_contraction, ddmp._isotropic_contraction)
    with native_reductions_forms(True):
        jaxpr = jax.make_jaxpr(jax.grad(fast))(dg.A, p)
        g_fast = jax.jit(jax.grad(fast, argnums=(0, 1)))(dg.A, p)
    padded = [e for e in _eqns(jaxpr.jaxpr) if e.primitive.name == "pad" and e.outvars[0].aval.shape == dg.A.shape]
    assert not padded, f"{len(padded)} padded copies of A in the gradient"
    g_ref = jax.jit(
        jax.grad(
            lambda A, p: loss(
                A,
                p,
                lambda q, A: jnp.einsum("...i,...nik->...nk", q, A),
                lambda q, A: jnp.einsum("...j,...jik->...ik", q, A),
            ),
            argnums=(0, 1),
        )
    )(dg.A, p)
    for a, b in zip(g_fast, g_ref):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12)
        assert float(jnp.abs(b).max()) > 0


@pytest.mark.parametrize("dim", [1, 2, pytest.param(3, marks=pytest.mark.slow)])
def test_add_corners_transposes_to_the_corner_slices(dim):
    """Reverse mode through the corner sums (E11, E12, E13, R3) evaluates `corners` of the
    cotangent: no loop over the corners carrying the whole cotangent of c (the transpose of the
    forward's slab loop), no padded copy of c per corner. Values, gradients, tangents and a
    batched second derivative against the sums of shifted copies."""
    rng = np.random.default_rng(40 + dim)
    cells = (3, 4, 2)[:dim]
    c = jnp.asarray(rng.normal(size=(2,) + cells + (2**dim, 2)))
    dc = jnp.asarray(rng.normal(size=c.shape))
    w = jnp.asarray(rng.normal(size=(2,) + tuple(n + 1 for n in cells) + (2,)))

    def loss(c, add):
        return jnp.sum(w * jnp.sin(add(c, dim)))

    jaxpr = jax.make_jaxpr(jax.grad(lambda c: loss(c, ddmp.add_corners)))(c)
    loops = [e for e in _eqns(jaxpr.jaxpr) if e.primitive.name in ("while", "scan")]
    assert len(loops) == 1, f"{len(loops)} loops in the gradient: the forward's slab loop and its transpose"
    padded = [e for e in _eqns(jaxpr.jaxpr) if e.primitive.name == "pad" and e.outvars[0].aval.shape == c.shape]
    assert not padded, f"{len(padded)} padded copies of c in the gradient"
    g = jax.grad(lambda c: loss(c, ddmp.add_corners))(c)
    g_ref = jax.grad(lambda c: loss(c, add_corners_shifted))(c)
    np.testing.assert_allclose(g, g_ref, rtol=RTOL, atol=1e-14)
    t = jax.jvp(lambda c: ddmp.add_corners(c, dim), (c,), (dc,))[1]
    np.testing.assert_allclose(t, add_corners_shifted(dc, dim), rtol=RTOL, atol=1e-14)
    hvp = jax.vmap(lambda v: jax.jvp(jax.grad(lambda c: loss(c, ddmp.add_corners)), (c,), (v,))[1])(jnp.stack([c, dc]))
    hvp_ref = jax.vmap(lambda v: jax.jvp(jax.grad(lambda c: loss(c, add_corners_shifted)), (c,), (v,))[1])(
        jnp.stack([c, dc])
    )
    np.testing.assert_allclose(hvp, hvp_ref, rtol=1e-11, atol=1e-13)
    assert float(jnp.abs(hvp_ref).max()) > 0


@pytest.mark.parametrize("shape", ["linear", "bspline2"])
@pytest.mark.parametrize("dim", [pytest.param(1, marks=pytest.mark.slow), 2, 3])  # 1D: the product of one factor
def test_stencil_weights_keep_their_product_in_derivatives(dim, shape):
    """The tensor-product weights S_n = prod_d S(x_d) (broadcast products of the 1D weights) and
    DDMP's beta (E9, one product reduction in the derivatives' primal too: jnp.prod's own rule
    recomputes it as products of slices, which XLA fused into every consumer) equal jnp.prod's of
    the 1D weights picked per node: values bitwise, first and second derivatives. The weights'
    reverse pass has no scatter (indexing the 1D weights by the stencil's offsets transposed to
    scatter-adds: the elastic impact's shape-function stage 0.32 -> 0.10 ms per step in its
    gradient's transpose)."""
    from jaxmpm.numerics import shapes

    rng = np.random.default_rng(60 + dim)
    grid = Grid(cells=(4, 3, 2)[:dim], h=0.25, origin=(0.0,) * dim)
    x = particles_on_faces(rng, grid, 40)
    make = linear_stencil if shape == "linear" else bspline2_stencil

    width = 2 if shape == "linear" else 3

    def by_node(f, k):
        """(N, S) the 1D values f(x_k) (N, width) picked by each stencil node's offset on axis k."""
        return f[:, stencil_offsets(dim, width)[:, k]]

    def weights(x, product):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(shapes, "_product_over_axes", product)
            st = make(grid, x)
            return st.w, st.dw, shapes.ddmp_beta(st.xi)

    def weights_reference(x):
        """The tensor products as jnp.prod over the 1D weights indexed per node."""
        st = make(grid, x)
        one_d = shapes.linear_weights_1d if shape == "linear" else shapes.bspline2_weights_1d
        w1 = [jnp.stack(one_d(st.xi[:, k]), 1) for k in range(dim)]
        dw1 = [jax.vmap(jax.jacfwd(lambda f: jnp.stack(one_d(f))))(st.xi[:, k]) / grid.h for k in range(dim)]
        w = jnp.prod(jnp.stack([by_node(w1[k], k) for k in range(dim)], -1), -1)
        dw = jnp.stack(
            [
                jnp.prod(jnp.stack([by_node(dw1[k] if e == k else w1[e], e) for e in range(dim)], -1), -1)
                for k in range(dim)
            ],
            -1,
        )
        return w, dw, jnp.prod(4 * st.xi * (1 - st.xi), -1)

    plain = lambda a: jnp.prod(a, -1)
    for a, b in zip(weights(x, shapes._product_over_axes), weights(x, plain)):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(weights(x, shapes._product_over_axes), jax.jit(weights_reference)(x)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)
    reverse = jax.make_jaxpr(
        jax.grad(
            lambda x: sum(
                jnp.sum(jnp.sin(a)) for a in make(grid, x).__dict__.values() if jnp.issubdtype(a.dtype, jnp.floating)
            )
        )
    )(x)
    assert not [e for e in _eqns(reverse.jaxpr) if "scatter" in e.primitive.name], "the weights' transpose scatters"
    primal = jax.make_jaxpr(lambda x, dx: jax.jvp(lambda x: weights(x, shapes._product_over_axes), (x,), (dx,)))(x, x)
    assert "reduce_prod" in {e.primitive.name for e in _eqns(primal.jaxpr)}, (
        "the derivative's primal lost the reduction"
    )
    u = [jnp.asarray(rng.normal(size=a.shape)) for a in weights(x, plain)]

    def loss(x, product):
        return sum(jnp.sum(ui * jnp.sin(3 * a)) for ui, a in zip(u, weights(x, product)))

    dx = jnp.asarray(rng.normal(size=x.shape))
    gradient = jax.jit(jax.grad(loss), static_argnums=1)
    g, g_ref = gradient(x, shapes._product_over_axes), gradient(x, plain)
    np.testing.assert_allclose(g, g_ref, rtol=1e-12, atol=1e-12)
    assert float(jnp.abs(g_ref).max()) > 0
    hessian_vector = jax.jit(
        lambda x, dx, product: jax.jvp(lambda x: gradient(x, product), (x,), (dx,))[1], static_argnums=2
    )
    hvp, hvp_ref = hessian_vector(x, dx, shapes._product_over_axes), hessian_vector(x, dx, plain)
    np.testing.assert_allclose(hvp, hvp_ref, rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("native", [False, True])
@pytest.mark.parametrize("dim", [1, 2, 3])
def test_stencil_contractions_equal_einsums(dim, native):
    """Both forms of the stencil contractions (their tangents reduced under jaxmpm.jit, unrolled
    otherwise) against einsums: values, gradients through the stencil's dependence on x, and,
    reduced, no padded copy of an (N, S, d) argument per slice in the gradient."""
    rng = np.random.default_rng(20 + dim)
    grid = Grid(cells=(4, 3, 2)[:dim], h=0.25, origin=(0.0,) * dim)
    st = linear_stencil(grid, particles_on_faces(rng, grid, 50))
    v = jnp.asarray(rng.normal(size=st.dw.shape))  # (N, S, d): nodal values at the stencil
    sig = jnp.asarray(rng.normal(size=(st.dw.shape[0], dim, dim)))
    np.testing.assert_allclose(stencil_outer(v, st.dw), jnp.einsum("nsa,nsb->nab", v, st.dw), rtol=RTOL, atol=1e-13)
    np.testing.assert_allclose(stencil_apply(sig, st.dw), jnp.einsum("nab,nsb->nsa", sig, st.dw), rtol=RTOL, atol=1e-13)
    # gradients with respect to both arguments, through the stencil's dependence on x too
    x = particles_on_faces(rng, grid, 50)

    def loss(f_outer, f_apply):
        def f(x, v, sig):
            dw = linear_stencil(grid, x).dw
            return jnp.sum(f_outer(v, dw) ** 2) + jnp.sum(jnp.sin(f_apply(sig, dw) + 0.3))

        return jax.grad(f, argnums=(0, 1, 2))

    with native_reductions_forms(native):
        fast = jax.jit(loss(stencil_outer, stencil_apply))(x, v, sig)
        jaxpr = jax.make_jaxpr(
            jax.grad(
                lambda v, sig, dw: jnp.sum(stencil_outer(v, dw) ** 2) + jnp.sum(jnp.sin(stencil_apply(sig, dw))),
                argnums=(0, 1, 2),
            )
        )(v, sig, st.dw)
    ref = jax.jit(loss(lambda a, b: jnp.einsum("nsa,nsb->nab", a, b), lambda m, b: jnp.einsum("nab,nsb->nsa", m, b)))(
        x, v, sig
    )
    for i, (a, b) in enumerate(zip(fast, ref)):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12)
        assert float(jnp.abs(b).max()) > 0 or (dim, i) == (1, 0)  # 1D: grad S does not depend on x
    padded = [e for e in _eqns(jaxpr.jaxpr) if e.primitive.name == "pad" and e.outvars[0].aval.shape == st.dw.shape]
    assert not (native and padded), f"{len(padded)} padded copies of an (N, S, d) argument in the gradient"


@pytest.mark.parametrize(
    "scatter_form", [pytest.param("offset", marks=pytest.mark.slow), "window"]
)  # offset: the benchmarks' reference
@pytest.mark.parametrize("shape", ["bspline2", "linear"])
@pytest.mark.parametrize("dim", [1, 2, 3])
def test_offset_transfers_equal_the_stencil_transfers(dim, shape, scatter_form):
    """transfer.scatter_by_offset / gather_by_offset (a loop over the stencil offsets, particles on
    the minor axis) and scatter_by_window (each particle's stencil block in one windowed scatter,
    particles in blocks: the APIC step's particle-to-grid transfer) against the (N, S, C) scatter
    and gather of shapes.Stencil, with APIC's contributions (mass, momentum with the affine term;
    velocity and the affine matrix back), values and gradients with respect to the particle data
    and positions. Particles on cell faces and nodes, nodes that no particle reaches, a last block
    of particles part empty (43 particles in blocks of 8)."""
    rng = np.random.default_rng(30 + dim)
    grid = Grid(cells=(7, 6, 5)[:dim], h=0.25, origin=(0.0, -0.5, 0.25)[:dim])
    n = 43
    x = particles_on_faces(rng, Grid(cells=(3, 3, 2)[:dim], h=grid.h, origin=grid.origin), n)  # nodes past them: empty
    m = jnp.asarray(rng.uniform(0.5, 2.0, n))
    v = jnp.asarray(rng.normal(size=(n, dim)))
    A = jnp.asarray(rng.normal(size=(n, dim, dim)))
    vn = jnp.asarray(rng.normal(size=(grid.n_nodes, dim)))
    stencil_of = bspline2_stencil if shape == "bspline2" else linear_stencil

    def by_stencil(x, m, v, A, vn):
        st = stencil_of(grid, x)
        w = st.w[..., None]
        mom = w * (m[:, None] * v)[:, None, :] + w * jnp.einsum("nab,nsb->nsa", A, st.dpos)
        g = scatter(st, None, jnp.concatenate([w * m[:, None, None], mom], -1), 1, grid.n_nodes)[0]
        vals = gather(st, None, vn[None])
        return g, jnp.sum(w * vals, 1), jnp.einsum("ns,nsa,nsb->nab", st.w, vals, st.dpos)

    def by_offset(x, m, v, A, vn):
        ost = offset_stencil(grid, x, shape)
        mv, At = (m[:, None] * v).T, jnp.transpose(A, (1, 2, 0))
        if scatter_form == "offset":
            contrib = lambda w, dpos: jnp.concatenate(
                [(w * m)[None], w * (mv + sum(At[:, k] * dpos[k] for k in range(dim)))]
            )
            g = scatter_by_offset(ost, contrib, dim + 1, grid.n_nodes, m.dtype)
        else:

            def contrib(w, dpos, m, mv, At):
                return [w * m] + [w * (mv[c] + sum(At[c, k] * dpos[k] for k in range(dim))) for c in range(dim)]

            g = scatter_by_window(ost, contrib, (m, mv, At), dim + 1, m.dtype, block=8)

        def accumulate(carry, w, dpos, vals):
            return carry[0] + w * vals, carry[1] + (w * vals)[:, None] * dpos[None]

        vp, B = gather_by_offset(ost, vn.T, accumulate, (jnp.zeros((dim, n)), jnp.zeros((dim, dim, n))))
        return g, vp.T, jnp.transpose(B, (2, 0, 1))

    args = (x, m, v, A, vn)
    ref, new = jax.jit(by_stencil)(*args), jax.jit(by_offset)(*args)
    assert float(jnp.max(ref[0][:, 0])) > 0 and int(jnp.sum(ref[0][:, 0] == 0)) > 0  # reached and unreached nodes
    for a, b in zip(new, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-13)
    weights = [jnp.asarray(rng.normal(size=r.shape)) for r in ref]
    loss = lambda f: lambda *a: sum(jnp.sum(w * jnp.sin(o)) for w, o in zip(weights, f(*a)))
    g_new = jax.jit(jax.grad(loss(by_offset), argnums=range(5)))(*args)
    g_ref = jax.jit(jax.grad(loss(by_stencil), argnums=range(5)))(*args)
    for a, b in zip(g_new, g_ref):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


def test_tangent_fence_passes_the_tangent_where_on_and_zero_where_off():
    """`step.tangent_fenced(x, on)` is x; its tangent and cotangent are x's where on (the step's
    dt > 0) and zero where off, in forward and reverse mode, batched (a per-member dt of an
    ensemble) and at second order; the step's conditional is in the derivative's program."""
    from jaxmpm.step import tangent_fenced

    x = jnp.linspace(-1.0, 2.0, 12).reshape(3, 2, 2)
    f = lambda x, on: jnp.sum(jnp.sin(tangent_fenced(x * x, on)))
    for on in (True, False):
        assert np.array_equal(tangent_fenced(x, jnp.asarray(on)), x)
        expected = 2 * x * jnp.cos(x * x) if on else jnp.zeros_like(x)
        np.testing.assert_allclose(jax.grad(f)(x, jnp.asarray(on)), expected, rtol=1e-14)
        t = jax.jvp(lambda x: f(x, jnp.asarray(on)), (x,), (jnp.ones_like(x),))[1]
        np.testing.assert_allclose(t, jnp.sum(expected), rtol=1e-14)
        h = jax.grad(lambda x: jnp.sum(jax.grad(f)(x, jnp.asarray(on))))(x)  # second order
        np.testing.assert_allclose(h, (2 * jnp.cos(x * x) - 4 * x * x * jnp.sin(x * x)) if on else 0 * x, rtol=1e-13)
    on = jnp.asarray([True, False, True])
    g = jax.vmap(jax.grad(lambda x, on: jnp.sum(jnp.sin(tangent_fenced(x * x, on)))))(x, on)
    np.testing.assert_allclose(g, jnp.where(on[:, None, None], 2 * x * jnp.cos(x * x), 0.0), rtol=1e-14)
    jaxpr = str(jax.make_jaxpr(jax.grad(f))(x, jnp.asarray(True)))
    assert "cond[" in jaxpr

    def tree(x, on):
        t = tangent_fenced({"a": x * x, "b": (2 * x, 3 * x)}, on)
        return jnp.sum(jnp.sin(t["a"])) + jnp.sum(t["b"][1])

    for on in (True, False):  # a pytree: one conditional
        expected = (2 * x * jnp.cos(x * x) + 3) if on else jnp.zeros_like(x)
        np.testing.assert_allclose(jax.grad(tree)(x, jnp.asarray(on)), expected, rtol=1e-14)


# ------------------------------------------------------------------ the GPU forms against the CPU's
def _form_scene(case):
    """Small scenes that take every transfer and DDMP corner sum the two forms write differently
    (jaxmpm/forms.py): APIC in 1D, 2D and 3D; DDMP musl in 1D, 2D, 3D and axisymmetric; two
    velocity fields in 1D (exchange, interface forces) and axisymmetric."""
    import dataclasses

    from impact_blocks import two_blocks

    import jaxmpm
    from jaxmpm.model.scene import Box, Phase, Scene
    from jaxmpm.model.scene import Grid as SceneGrid
    from jaxmpm.scenes import basic, impact

    fluid = jaxmpm.Material.make("fluid", "linear_fluid", rho0=1.0, K=400.0)
    steel = jaxmpm.Material.make("steel", "linear_elastic", rho0=7800.0, E=200e9, nu=0.3)
    if case == "apic-1d":
        return Scene(
            grid=SceneGrid(cells=(12,), h=0.1),
            shape="bspline2",
            transfer="apic",
            materials=(fluid,),
            phases=(Phase("a", "fluid", Box((0.3,), (0.8,)), velocity=(0.7,)),),
            gravity=(-9.8,),
        )
    if case in ("apic-2d", "apic-3d"):
        return basic.mpm88(n_grid=8, dim=int(case[-2]), ppc_scale=0.005 if case == "apic-2d" else 1.0)
    if case == "ddmp-1d":
        return basic.vibrating_bar(cells=10)
    if case == "ddmp-2d":
        return basic.elastic_impact(resolution=0.25)
    if case == "ddmp-3d":
        return dataclasses.replace(basic.mpm88(n_grid=8, dim=3), shape="ddmp", transfer="musl")
    if case == "ddmp-axisymmetric":
        return Scene(
            grid=SceneGrid(cells=(5, 8), h=1e-3, origin=(0.0, 0.0)),
            axisymmetric=True,
            materials=(steel,),
            phases=(Phase("rod", "steel", Box((0.0, 1e-3), (3e-3, 6e-3)), velocity=(0.0, -50.0)),),
        )
    if case == "two-fields-1d":
        return two_blocks(1.0, "off", cells=24)  # the continuity form's transpose: in the axisymmetric case
    if case == "two-fields-axisymmetric":
        return impact.debris_cloud(resolution=0.75, fields=2)
    raise ValueError(case)


def _steps_and_gradient(scene, form, n_steps=3):
    """n_steps of scene's step at a fixed dt traced in the given form, and the gradient of a
    weighted sum of the final positions, velocities and stresses with respect to the initial
    positions and velocities (float64)."""
    import dataclasses

    import jaxmpm
    from jaxmpm.numerics.forms import transfer_forms

    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.initial_state(scene, params)
    dt = 0.2 * float(jaxmpm.cfl_limit(scene, params, s0))
    rng = np.random.default_rng(5)
    wx, wv = (jnp.asarray(rng.normal(size=s0.x.shape)) for _ in range(2))
    ws = jnp.asarray(rng.normal(size=s0.stress.shape))
    with transfer_forms(form):
        step = jaxmpm.make_step(scene)

        def run(x, v):
            s = dataclasses.replace(s0, x=x, v=v)
            for _ in range(n_steps):
                s = step(params, s, jnp.inf, dt)
            return s

        def loss(x, v):  # and the final state: forward and gradient in one compiled program
            s = run(x, v)
            scale = jax.lax.stop_gradient(jnp.max(jnp.abs(s.stress))) + 1.0  # Pa: the final stresses' size
            return jnp.sum(wx * s.x) / scene.grid.h + jnp.sum(wv * s.v) + jnp.sum(ws * jnp.sin(s.stress / scale)), s

        (_, final), grad = jaxmpm.jit(jax.value_and_grad(loss, argnums=(0, 1), has_aux=True))(s0.x, s0.v)
    return s0, final, grad


FORM_CASES = [
    "apic-1d",
    "apic-2d",
    pytest.param("apic-3d", marks=pytest.mark.slow),
    pytest.param("ddmp-1d", marks=pytest.mark.slow),
    pytest.param("ddmp-2d", marks=pytest.mark.slow),
    pytest.param("ddmp-3d", marks=pytest.mark.slow),
    "ddmp-axisymmetric",
    pytest.param("two-fields-1d", marks=pytest.mark.slow),
    pytest.param("two-fields-axisymmetric", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("case", FORM_CASES)
def test_gpu_forms_equal_the_cpu_forms(case):
    """The steps traced in the GPU form (every stencil offset in one gather and one scatter-add,
    DDMP's corner sums as one fused sum; forced on the CPU) equal the CPU form's: every state
    value after three steps to round-off, and the gradient of the final positions, velocities and
    stresses with respect to the initial positions and velocities to 1e-10 relative."""
    scene = _form_scene(case)
    (s0, cpu, g_cpu), (_, gpu, g_gpu) = (_steps_and_gradient(scene, form) for form in ("cpu", "gpu"))
    for name in ("x", "v", "stress", "C", "F", "volume", "energy"):
        a, b = getattr(gpu, name, None), getattr(cpu, name, None)
        if b is None:
            continue
        scale = float(jnp.max(jnp.abs(b))) or 1.0
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * scale, err_msg=name)
    assert float(jnp.max(jnp.abs(cpu.x - s0.x))) > 0, "the steps moved no particle"
    for a, b in zip(g_gpu, g_cpu):
        scale = float(jnp.max(jnp.abs(b)))
        assert scale > 0
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * scale)


def test_gpu_form_has_no_loop_over_offsets_or_corners():
    """The GPU form's traced step has no loop (the CPU form loops over the stencil offsets in APIC's
    grid-to-particle transfer and over the cell corners in DDMP's sums), and each form is the one
    the context, the environment (JAXMPM_TRANSFER_FORM) and the backend pick, in that order."""
    import os

    import jaxmpm
    from jaxmpm.numerics.forms import ENV, transfer_form, transfer_forms
    from jaxmpm.scenes import basic

    for scene in (basic.mpm88(n_grid=8, ppc_scale=0.005), basic.elastic_impact(resolution=0.25)):
        params = jaxmpm.default_params(scene)
        s0 = jaxmpm.initial_state(scene, params)
        loops = {}
        for form in ("cpu", "gpu"):
            with transfer_forms(form):
                jaxpr = jax.make_jaxpr(jaxmpm.make_step(scene))(params, s0, jnp.inf, 1e-6)
            loops[form] = [e for e in _eqns(jaxpr.jaxpr) if e.primitive.name in ("while", "scan")]
        assert loops["cpu"] and not loops["gpu"], (scene.name, {k: len(v) for k, v in loops.items()})
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv(ENV, raising=False)
        assert transfer_form() == ("cpu" if jax.default_backend() == "cpu" else "gpu")
        mp.setenv(ENV, "gpu")
        assert transfer_form() == "gpu"
        with transfer_forms("cpu"):
            assert transfer_form() == "cpu"
        mp.setenv(ENV, "fast")
        with pytest.raises(ValueError, match="JAXMPM_TRANSFER_FORM = 'fast' is invalid: allowed auto | cpu | gpu"):
            transfer_form()
    with pytest.raises(ValueError, match="allowed auto"):
        with transfer_forms("tpu"):
            pass
    assert os.environ.get(ENV) in (None, "auto", "cpu", "gpu")
