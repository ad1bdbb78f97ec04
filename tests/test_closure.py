"""The continuous-to-disperse closure (E4, E5, E8): alpha = 1 - tanh(eps_ps / C_h) and the
relaxation B of the fragmented part toward the ambient pressure."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
import jaxmpm.shapes
import jaxmpm.transfer
from jaxmpm.scene import Box, Grid, Phase, Scene

ROCK = jaxmpm.Material.make("rock", "hypoelastic", rho0=2000.0, E=2.0e9, nu=0.25)   # 1D: c = 1000 m/s
P0 = 5.0e6


def block(c_h=0.1, cells=50, t_end=1e-4, **kw):
    return Scene(grid=Grid(cells=(cells,), h=1.0 / cells), materials=(ROCK,),
                 phases=(Phase("block", "rock", Box((0.4,), (0.6,))),), c_h=c_h, t_end=t_end, n_out=10, **kw)


def prepared(scene, eps, pressure=0.0, strain_rate=0.0):
    params = jaxmpm.default_params(scene)
    s = jaxmpm.init_state(scene, params)
    E = float(params.phases["block"]["E"])
    n = s.x.shape[0]
    return params, dataclasses.replace(
        s, eps_ps=jnp.full(n, eps), stress=jnp.full((n, 1, 1), -pressure),
        energy=jnp.full(n, pressure**2 / (2 * E * 2000.0)),           # stored elastic energy, J/kg
        v=strain_rate * (s.x - 0.5))


def energy(s):
    return float(jaxmpm.diagnostics.kinetic_energy(s) + jaxmpm.diagnostics.internal_energy(s))


def test_intact_material_follows_the_velocity_divergence_as_without_closure():
    a_scene, b_scene = block(c_h=0.1), block(c_h=None)
    pa, sa = prepared(a_scene, 0.0, P0)
    pb, sb = prepared(b_scene, 0.0, P0)
    fa, _ = jaxmpm.simulate(a_scene, pa, sa, progress=False)
    fb, _ = jaxmpm.simulate(b_scene, pb, sb, progress=False)
    assert float(jaxmpm.diagnostics.kinetic_energy(fb)) > 0.1 * energy(sb)   # it does expand elastically
    for name in ("x", "v", "stress", "volume", "energy"):
        np.testing.assert_allclose(np.asarray(getattr(fa, name)), np.asarray(getattr(fb, name)), rtol=1e-13, atol=1e-300)


def test_fragmented_block_keeps_its_density_while_its_volume_fraction_falls():
    scene = block(c_h=0.01, t_end=2e-3)
    params, s0 = prepared(scene, 1.0, 0.0, strain_rate=200.0)       # alpha = 1 - tanh(100)
    final, _ = jaxmpm.simulate(scene, params, s0, progress=False)
    extent0 = float(s0.x.max() - s0.x.min())
    extent1 = float(final.x.max() - final.x.min())
    assert extent1 > 1.3 * extent0
    rho0, rho1 = s0.mass / s0.volume, final.mass / final.volume
    np.testing.assert_allclose(np.asarray(rho1), np.asarray(rho0), rtol=1e-9)
    theta = jaxmpm.transfer.scatter_weighted(jaxmpm.shapes.stencil(scene, final.x), None, final.volume[:, None], 1, scene.grid.n_nodes)[0, :, 0] / scene.grid.h
    assert float(theta.max()) < 0.85                     # was 1 inside the block


@pytest.mark.parametrize("state", ["fragmented", "intact"])
def test_precompressed_block_in_vacuum(state):
    """Fragmented: unloads to zero pressure within a few acoustic times of a cell, the released
    elastic energy stays as heat (kinetic + internal conserved). Intact: elastic response."""
    scene = block(c_h=0.01, t_end=6 * (1.0 / 50) / 1000.0)        # 6 tau, tau = h / c
    params, s0 = prepared(scene, 1.0 if state == "fragmented" else 0.0, P0)
    final, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    p = -np.asarray(final.stress[:, 0, 0])
    e = [energy(jax.tree.map(lambda a: a[i], hist)) for i in range(len(hist.t))]
    if state == "fragmented":
        assert np.abs(p).max() < 0.01 * P0
        assert float(jaxmpm.diagnostics.kinetic_energy(final)) < 1e-6 * e[0]
        np.testing.assert_allclose(e, e[0], rtol=0.02)
    else:
        assert np.abs(p).max() > 0.5 * P0            # the interior still holds its pressure
        assert float(jaxmpm.diagnostics.kinetic_energy(final)) > 0.05 * e[0]


@pytest.mark.parametrize("gas_field", [1, 0], ids=["two fields", "one field"])
def test_fragmented_block_in_pressurised_gas_relaxes_to_the_gas_pressure(gas_field):
    """(E8) the ambient pressure is the common pressure of the OTHER phases, however the phases
    are grouped into velocity fields: with the gas in a field of its own (drag, interface forces)
    and with debris and gas sharing one field, the debris relaxes to the gas pressure."""
    gas = jaxmpm.Material.make("gas", "linear_fluid", rho0=10.0, K=1.0e7)
    p_gas, K_gas = 1.0e6, 1.0e7
    box = Box((0.0,), (1.0,))
    walls = jaxmpm.Boundary(faces=(("x_lo", "fixed"), ("x_hi", "fixed")))
    scene = Scene(grid=Grid(cells=(20,), h=0.05), materials=(ROCK, gas), boundary=walls, shape="linear",
                  phases=(Phase("debris", "rock", box, field=0, fraction=0.5),
                          Phase("gas", "gas", box, field=gas_field, fraction=0.5)),
                  drag=1.0 if gas_field else None, c_h=0.01, t_end=10 * 0.05 / 1000.0, n_out=5)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    sl = jaxmpm.state.phase_slices(scene)
    J = 1 - p_gas / K_gas
    F = s0.F.at[sl[1]].set(J)
    stress = s0.stress.at[sl[1]].set(-p_gas)
    s0 = dataclasses.replace(s0, F=F, stress=stress, volume=s0.volume.at[sl[1]].multiply(J),
                             eps_ps=s0.eps_ps.at[sl[0]].set(1.0))
    final, _ = jaxmpm.simulate(scene, params, s0, progress=False)
    p_debris = -np.asarray(final.stress[sl[0], 0, 0])
    np.testing.assert_allclose(p_debris, p_gas, rtol=0.02)


@pytest.mark.parametrize("over_pressure, clipped", [(P0, False), (1.0e10, True), (-1.0e10, True)])
def test_e8_relaxation_rate_is_the_formula_with_its_strain_clipped_at_one_e_fold(over_pressure, clipped):
    """(E8) B = (1 - alpha)(p - p_amb) / (K tau), tau = h / c, over the step as the exact exponential
    (1 - exp(-dt / tau)) / dt, by hand from the model's K and c; where |p - p_amb| / K exceeds
    EQUILIBRATING_STRAIN_MAX = 1 (here 7.5 either way, in vacuum) the strain is clipped to +-1,
    so the volume changes by at most one e-fold per relaxation time."""
    from jaxmpm.constitutive import (EQUILIBRATING_STRAIN_MAX, bulk_modulus_and_wave_speed, closure_alpha,
                                     material_volume_rate)
    from jaxmpm.step import Layout

    scene = block(c_h=0.01)
    params, s = prepared(scene, 1.0, over_pressure)
    lay = Layout.of(scene)
    dt = 2e-5
    rate = np.asarray(material_volume_rate(lay, params, s, jnp.zeros((s.x.shape[0], 1, 1)), dt, jnp.zeros_like(s.mass)))
    K, c = (np.asarray(a) for a in bulk_modulus_and_wave_speed(lay, params, s))
    alpha = np.asarray(closure_alpha(lay, params, s))
    tau = scene.grid.h / c
    strain = over_pressure / K
    assert (np.abs(strain) > EQUILIBRATING_STRAIN_MAX).all() == clipped
    expected = (1 - alpha) * np.clip(strain, -1.0, 1.0) * (1 - np.exp(-dt / tau)) / dt
    np.testing.assert_allclose(rate, expected, rtol=1e-12)
    assert float(alpha.max()) < 1e-12 and (dt / tau > 0.5).all()     # fragmented; the exponential matters


def test_alpha_is_smooth_and_grad_wrt_c_h_matches_finite_difference():
    scene = block(c_h=0.05, t_end=4e-5)
    params, s0 = prepared(scene, 0.05, P0)              # eps_ps = C_h: alpha depends on C_h
    n = jaxmpm.plan_steps(scene, params, s0, scene.t_end)

    def kinetic(c_h):
        final = jaxmpm.simulate(scene, dataclasses.replace(params, c_h=c_h), s0, n_steps=n)[0]
        return jaxmpm.diagnostics.kinetic_energy(final)

    f = jax.jit(kinetic)
    g = float(jax.grad(kinetic)(jnp.asarray(0.05)))
    fd = float((f(0.05 * (1 + 1e-6)) - f(0.05 * (1 - 1e-6))) / (2e-6 * 0.05))
    np.testing.assert_allclose(g, fd, rtol=1e-5)
    assert g > 0                                         # larger C_h: more intact, more elastic push
    params0, s00 = prepared(scene, 0.0, P0)
    g0 = jax.grad(lambda c: jaxmpm.simulate(scene, dataclasses.replace(params0, c_h=c), s00, n_steps=n)[0].x.sum())(0.05)
    assert np.isfinite(float(g0))


def test_no_closure_no_closure_code():
    for scene, expect in ((block(c_h=None), False), (block(c_h=0.1), True)):
        params = jaxmpm.default_params(scene)
        state = jaxmpm.init_state(scene, params)
        closed = jax.make_jaxpr(jaxmpm.make_step(scene))(params, state)
        leaves = jax.tree.leaves((params, state))
        var = closed.jaxpr.invars[[i for i, a in enumerate(leaves) if a is params.c_h][0]]
        assert any(var in e.invars for e in closed.jaxpr.eqns) == expect


def _scatter_adds(scene):
    """The number of scatter-adds in the traced step of `scene` (nested programs included)."""
    params = jaxmpm.default_params(scene)
    return str(jax.make_jaxpr(jaxmpm.make_step(scene))(params, jaxmpm.init_state(scene, params))).count("scatter-add")


def test_the_per_phase_ambient_adds_one_scatter_only_where_a_field_holds_several_phases():
    """(E8) with each phase in a field of its own the closure's ambient pressure reuses the interface
    forces' nodal quantities (no scatter more than without the closure); with both phases in one
    field it takes one scatter onto a grid per phase."""
    gas = jaxmpm.Material.make("gas", "linear_fluid", rho0=10.0, K=1.0e7)

    def scene(gas_field, c_h):
        return Scene(grid=Grid(cells=(20,), h=0.05), materials=(ROCK, gas), shape="linear",
                     phases=(Phase("debris", "rock", Box((0.0,), (1.0,)), field=0, fraction=0.5),
                             Phase("gas", "gas", Box((0.0,), (1.0,)), field=gas_field, fraction=0.5)),
                     drag=1.0 if gas_field else None, c_h=c_h, t_end=1e-4)

    for gas_field, extra in ((1, 0), (0, 1)):
        with_closure, without = _scatter_adds(scene(gas_field, 0.01)), _scatter_adds(scene(gas_field, None))
        assert with_closure == without + extra, (gas_field, with_closure, without)


def test_bad_c_h():
    with pytest.raises(ValueError, match=r"effects\.c_h = 0\.0 is invalid: allowed > 0"):
        block(c_h=0.0)
    with pytest.raises(ValueError, match=r"effects\.c_h = -1\.0 is invalid"):
        block(c_h=-1.0)
