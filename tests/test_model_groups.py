"""Phases of one model kind are updated together (`constitutive.per_model`): their constants become
per-particle arrays. The update must equal each phase's own update with its own constants, in
values and gradients, whether the kind's phases are adjacent in particle order or not."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.stages.constitutive import constitutive
from jaxmpm.stages.phase_models import bulk_modulus_and_wave_speed, model_groups
from jaxmpm.materials import MatPoint, library_material, model_of
from jaxmpm.model.scene import Box, Grid, Phase, Scene
from jaxmpm.stages.layout import Layout

jax.config.update("jax_enable_x64", True)

ELASTIC = jaxmpm.Material.make("rubberish", "linear_elastic", rho0=1200.0, E=5e8, nu=0.45)


def scene_of(order):
    """2D scene of three boxes side by side: phases named by `order` from two hydrocode metals of one
    model kind (al2024, steel_4340) and one linear-elastic solid, with their own constants."""
    mats = {"al": library_material("al2024"), "steel": library_material("steel_4340"), "soft": ELASTIC}
    phases = tuple(
        Phase(name, mats[name].key, Box((0.1 + 0.25 * i, 0.1), (0.3 + 0.25 * i, 0.4)), field=0)
        for i, name in enumerate(order)
    )
    return Scene(
        grid=Grid(cells=(40, 20), h=0.025), materials=tuple(mats[n] for n in order), phases=phases, t_end=1e-6, n_out=1
    )


def perturbed_state(scene, params, key):
    s = jaxmpm.init_state(scene, params)
    n, d = s.x.shape
    k1, k2, k3 = jax.random.split(key, 3)
    return dataclasses.replace(
        s,
        volume=s.volume * (1 + 0.02 * jax.random.normal(k1, (n,))),
        energy=s.energy + 1e4 * jax.random.uniform(k2, (n,)),
        eps_ps=0.05 * jax.random.uniform(k3, (n,)),
    )


def per_phase_reference(lay, params, state, L, dt):
    """The update phase by phase with scalar constants, as each model is written."""
    scene = lay.scene
    vol = state.volume * jnp.exp(dt * jnp.trace(L, axis1=1, axis2=2))
    D = 0.5 * (L + jnp.swapaxes(L, 1, 2))
    work = dt * 0.5 * (vol + state.volume) / state.mass
    mp = MatPoint(
        state.F,
        state.stress,
        jaxmpm.stages.phase_models.pressure(lay, state),
        state.energy,
        state.eps_ps,
        state.damage,
        state.mass / state.volume,
        state.mass / vol,
    )
    outs = []
    for p, sl in zip(scene.phases, lay.slices):
        outs.append(
            model_of(scene.material(p).model).update(
                params.phases[p.name], MatPoint(*(a[sl] for a in mp)), L[sl], D[sl], dt, work[sl], None, None
            )
        )
    new = MatPoint(*(jnp.concatenate(a) for a in zip(*outs)))
    return dict(
        F=new.F, stress=new.stress, energy=new.energy, eps_ps=new.eps_ps, pressure=new.pressure, damage=new.damage
    )


@pytest.mark.parametrize("order, contiguous", [(("al", "steel", "soft"), True), (("al", "soft", "steel"), False)])
def test_grouped_update_equals_the_per_phase_update(order, contiguous):
    scene = scene_of(order)
    lay = Layout.of(scene)
    groups = model_groups(lay)
    metal = [g for g in groups if len(g[1]) == 2]
    assert len(groups) == 2 and len(metal) == 1
    assert isinstance(metal[0][2], slice) == contiguous
    params = jaxmpm.default_params(scene)
    state = perturbed_state(scene, params, jax.random.PRNGKey(0))
    n, d = state.x.shape
    L = 2e5 * jax.random.normal(jax.random.PRNGKey(1), (n, d, d))  # 1/s: yields the metals in one step
    dt = 2e-7
    got = jax.jit(lambda p, s, L: constitutive(lay, p, s, L, dt))(params, state, L)
    ref = jax.jit(lambda p, s, L: per_phase_reference(lay, p, s, L, dt))(params, state, L)
    assert float(jnp.max(got["eps_ps"] - state.eps_ps)) > 1e-4  # the metals flowed plastically
    for k, v in ref.items():
        np.testing.assert_allclose(got[k], v, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(v)) + 1e-300), err_msg=k)
    K, c = bulk_modulus_and_wave_speed(lay, params, state)
    rho = state.mass / state.volume
    for p, sl in zip(scene.phases, lay.slices):
        m, cp = model_of(scene.material(p).model), params.phases[p.name]
        np.testing.assert_allclose(
            K[sl], m.bulk_modulus(cp, rho[sl], state.energy[sl], 3) * jnp.ones_like(rho[sl]), rtol=1e-13
        )
        np.testing.assert_allclose(
            c[sl], m.wave_speed(cp, rho[sl], state.energy[sl], 3) * jnp.ones_like(rho[sl]), rtol=1e-13
        )


def test_grouped_update_has_the_per_phase_gradients():
    """d(loss)/d(L) and d(loss)/d(one phase's constant) through the grouped update equal the
    per-phase ones: the constants of each phase reach only its own particles."""
    scene = scene_of(("al", "soft", "steel"))
    lay = Layout.of(scene)
    params = jaxmpm.default_params(scene)
    state = perturbed_state(scene, params, jax.random.PRNGKey(2))
    n, d = state.x.shape
    L = 2e5 * jax.random.normal(jax.random.PRNGKey(3), (n, d, d))
    dt = 2e-7
    steel = scene.phases[2].name

    def loss(fn, G, L):
        p = params.with_constant(steel, "G", G)
        out = fn(lay, p, state, L, dt)
        return jnp.sum(out["stress"] ** 2) * 1e-18 + jnp.sum(out["eps_ps"])

    G0 = params.phases[steel]["G"]
    grouped = jax.jit(jax.grad(lambda G, L: loss(constitutive, G, L), argnums=(0, 1)))(G0, L)
    ref = jax.jit(jax.grad(lambda G, L: loss(per_phase_reference, G, L), argnums=(0, 1)))(G0, L)
    assert abs(float(ref[0])) > 0
    np.testing.assert_allclose(grouped[0], ref[0], rtol=1e-10)
    np.testing.assert_allclose(grouped[1], ref[1], rtol=1e-10, atol=1e-10 * float(jnp.max(jnp.abs(ref[1]))))
