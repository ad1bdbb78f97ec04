"""A run whose CFL step collapses is blowing up: the host driver stops it with a message naming the
fastest particle, instead of crawling on in ever shorter steps (jaxmpm.run.health.step_collapse)."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.model.scene import Box, Grid, Phase, Scene
from jaxmpm.run.health import STEP_COLLAPSE, reference_step, step_collapse

GAS = jaxmpm.Material.make("gas", "ideal_gas", rho0=1.0, gamma=1.4, p0=1e-4)  # sound speed 0.012 m/s


def falling_gas(gravity: float = 9.81) -> Scene:
    """A gas block at rest under gravity in a 10 x 10 m grid."""
    return Scene(
        grid=Grid(cells=(20, 20), h=0.5),
        materials=(GAS,),
        phases=(Phase("block", "gas", Box((4.0, 6.0), (6.0, 8.0))),),
        gravity=(0.0, -gravity),
        t_end=0.9,
        n_out=3,
        name="falling_gas",
    )


def test_the_message_names_the_fastest_particle_below_the_allowed_step():
    scene = falling_gas()
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    state = dataclasses.replace(state, v=state.v.at[3].set(jnp.asarray([3e6, -4e6])))
    assert step_collapse(scene, state, 1.01 * STEP_COLLAPSE, 1.0) is None
    message = step_collapse(scene, state, 0.99 * STEP_COLLAPSE, 1.0)
    assert "blowing up" in message and "particle, 3 of phase 'block', moves at 5e+06 m/s" in message, message


def test_the_reference_step_allows_a_fall_through_the_grid():
    """cfl h / sqrt(2 |g| L), L the grid's diagonal (14.1 m): 0.3 * 0.5 / 16.7 m/s."""
    scene = falling_gas()
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    expected = 0.3 * 0.5 / np.sqrt(2 * 9.81 * np.hypot(10.0, 10.0))
    assert reference_step(scene, params, state, 1.0) == pytest.approx(expected, rel=1e-12)
    assert reference_step(scene, params, state, 1e-4) == 1e-4
    still = dataclasses.replace(scene, gravity=(0.0, 0.0))
    assert reference_step(still, jaxmpm.default_params(still), state, 2.0) == 2.0


def test_the_driver_stops_a_run_whose_step_collapses(monkeypatch):
    """The wiring: with the reference step made 1e4 times the run's own, the first chunk's CFL step
    lies below STEP_COLLAPSE of it and the run stops with the message. (In a script run with XLA's
    default optimisation, the `tensile` debris cloud at resolution 2, C_h = 1, every particle moved
    half a cell along z, stopped this way at t = 2.53 us, its step 1/2623 of the first, a projectile
    particle at 1.5e7 m/s at the grid's outer wall; unchecked, that run crawled on for more than 25
    minutes. The fragmented cloud is chaotic: the suite's XLA settings give another history.)"""
    from jaxmpm.run import driver

    real = driver.reference_step
    monkeypatch.setattr(driver, "reference_step", lambda *a: 1e4 * real(*a))
    scene = dataclasses.replace(falling_gas(), gravity=(0.0, 0.0), t_end=1.0)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    with pytest.raises(FloatingPointError, match=r"falling_gas: the run is blowing up at t = .* of phase 'block'"):
        jaxmpm.simulate(scene, params, s0, progress=False)
    monkeypatch.setattr(driver, "reference_step", real)
    scene = dataclasses.replace(scene, body_force=True)  # body forces: no reference, no check
    assert real(scene, jaxmpm.default_params(scene), s0, 1e-3) is None
    params = jaxmpm.default_params(scene)
    final, _ = jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), progress=False)
    assert float(final.t) == pytest.approx(1.0)
