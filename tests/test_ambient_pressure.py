"""The pressure of the surroundings (Scene.ambient_pressure, jaxmpm.stages.ambient): the grid sees
the gauge stress sigma + p_a I.

A gas at an ambient pressure fills a closed box at rest: with the absolute stress the force of its
particles' own pressure depends on where they sit in their cells, in proportion to p itself, and
grid modes grow from round-off (library air at 1 atm: 1e-9 -> 21 m/s in 400 steps with DDMP);
with the gauge stress it stays at rest. The gauge is the same physics as the absolute stress
with the void at p_a: a column at p_a collapsing beside that void moves as the same column at
zero pressure beside vacuum, to round-off, and its energy, with the surroundings' p_a V, changes
by the same amount.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm import Box, Grid, Phase, Scene

from test_fluids import A, G, dam_break, water

ATM = 101325.0  # Pa
H = 0.0057  # m: the cell of the dam break's two-field scene at 10 cells per column width


def gas_box(shape: str, ambient_pressure: float | None, cells: int = 16) -> Scene:
    """Library air at 1 atm filling a closed box of cells x cells cells of 5.7 mm, slip walls,
    2 x 2 particles per cell, no gravity."""
    walls = jaxmpm.Boundary(faces=tuple((f, "slip") for f in ("x_lo", "x_hi", "y_lo", "y_hi")))
    return Scene(
        grid=Grid(cells=(cells, cells), h=H),
        phases=(Phase("air", "air", Box((0.0, 0.0), (cells * H, cells * H)), ppc=2),),
        boundary=walls,
        shape=shape,
        ambient_pressure=ambient_pressure,
        name="gas_box",
    )


def largest_speed_after(scene: Scene, steps: int, dt: float, v0: float = 1e-9) -> tuple[float, float]:
    """Start every particle at rest plus a random velocity of about v0 (m/s, seeded), run `steps`
    steps of dt (s). -> (largest speed at the start, after) in m/s."""
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    v = v0 * np.random.default_rng(0).standard_normal(s0.v.shape)
    s0 = dataclasses.replace(s0, v=jnp.asarray(v, s0.v.dtype))
    step = jaxmpm.make_step(scene)
    s = jax.jit(lambda s: jax.lax.fori_loop(0, steps, lambda i, s: step(params, s, jnp.inf, dt), s))(s0)
    speed = lambda s: float(jnp.max(jnp.linalg.norm(s.v, axis=-1)))
    return speed(s0), speed(s)


ABSOLUTE = pytest.mark.xfail(
    strict=True,
    reason="known limitation (issue 49): with the absolute stress, the particle quadrature of a "
    "uniform pressure pushes the nodes in proportion to the pressure as the particles move within "
    "their cells; a gas's bulk modulus (1.4 p for air) does not hold it",
)


@pytest.mark.parametrize(
    "shape, ambient",
    [
        ("ddmp", ATM),
        ("linear", ATM),
        pytest.param("ddmp", None, marks=ABSOLUTE),
        pytest.param("linear", None, marks=ABSOLUTE),
    ],
)
def test_gas_at_the_ambient_pressure_stays_at_rest(shape, ambient):
    """Air at 1 atm in a closed 16 x 16 box, float64, dt = 5e-6 s (CFL 0.3), from random particle
    velocities of 1e-9 m/s: after 400 steps (2 ms) no particle is faster than 10x the start.
    Measured with the gauge stress: 3.5-3.9e-9 m/s throughout 2,000 steps (DDMP and linear; the
    start's largest is 3.6e-9). With the absolute stress: 21 m/s (DDMP; 1.3e4 /s, the same at
    dt = 2.5e-6 and 1.25e-6 s) and 14 m/s after 200 steps (linear)."""
    start, end = largest_speed_after(gas_box(shape, ambient), 400, 5e-6)
    assert end < 10 * start, (start, end)


def column(shape: str, p0: float, ambient_pressure: float | None) -> Scene:
    """The dam break's Tait column (c = 25 m/s) at 5 cells per width, with p0 (Pa) its pressure at
    rest, beside a void at ambient_pressure (None: vacuum)."""
    scene = dam_break(5, 1.0, shape=shape, ambient_pressure=ambient_pressure)
    return dataclasses.replace(scene, materials=(water(p0=p0),))


def run_steps(scene: Scene, steps: int):
    """-> (params, initial state, state after `steps` steps of 0.3 h / 25 m/s)."""
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    step = jaxmpm.make_step(scene)
    dt = 0.3 * scene.grid.h / 25.0
    return params, s0, jax.jit(lambda s: jax.lax.fori_loop(0, steps, lambda i, s: step(params, s, jnp.inf, dt), s))(s0)


@pytest.mark.parametrize("energy_update", ["midpoint", "compatible"])
@pytest.mark.parametrize("shape", ["ddmp", "linear"])
def test_a_column_at_the_ambient_pressure_moves_as_one_at_zero_beside_vacuum(shape, energy_update):
    """Tait water at p0 = 1 atm beside a void at 1 atm collapses under gravity exactly as the same
    water at p0 = 0 beside vacuum (the gauge stress is the same physics): positions to 1e-12 h and
    velocities to 1e-11 m/s after 300 steps (T = 0.55; measured 5e-15 h and 1e-14 m/s with DDMP,
    1e-14 h and 3e-14 m/s with linear shapes; the column is at 0.48-0.66 m/s). The energy,
    with the surroundings' p_a V, changes by the same amount to 1e-9 m g a; the internal energy
    alone differs by p_a dV = 0.045 m g a (measured, DDMP). With the absolute stress the column
    at 1 atm beside vacuum goes non-finite within these steps. With energy_update = 'compatible'
    the internal energy takes the grid's gauge work and p_a on the volume change, and the two
    energies change by the same amount as well (measured: -1.141e-3 and -2.985e-4 m g a for DDMP and
    linear shapes, both columns, against -1.159e-3 and -2.832e-4 with 'midpoint'; gravity's work is
    the part the compatible form does not make exact)."""

    def column_with(p0, pa):
        return dataclasses.replace(column(shape, p0, pa), energy_update=energy_update)

    pa, sa0, sa = run_steps(column_with(ATM, ATM), 300)
    pb, sb0, sb = run_steps(column_with(0.0, None), 300)
    h = A / 5
    assert float(jnp.max(jnp.abs(sa.x - sb.x))) < 1e-12 * h
    assert float(jnp.max(jnp.abs(sa.v - sb.v))) < 1e-11
    assert float(jnp.max(jnp.abs(sb.v))) > 0.4  # it did collapse
    mga = float(jnp.sum(sa0.mass)) * G * A
    energy = jaxmpm.diagnostics.total_energy
    dE_gauge = float(energy(column_with(ATM, ATM), pa, sa) - energy(column_with(ATM, ATM), pa, sa0))
    dE_zero = float(energy(column_with(0.0, None), pb, sb) - energy(column_with(0.0, None), pb, sb0))
    assert abs(dE_gauge - dE_zero) < 1e-9 * mga, (dE_gauge / mga, dE_zero / mga)
    work = float(jaxmpm.diagnostics.surroundings_energy(sa, pa.ambient_pressure))
    work -= float(jaxmpm.diagnostics.surroundings_energy(sa0, pa.ambient_pressure))
    assert abs(work) > 1e-2 * mga  # the surroundings' term is not negligible here


def test_ambient_pressure_zero_is_the_absolute_stress_and_a_scene_option():
    """ambient_pressure = 0 gives what None gives, to the bit; the option goes through a scene
    file; bad values and the closure are refused, naming the field."""
    from jaxmpm.io.scenefile import scene_from_toml, scene_to_toml

    scene = column("ddmp", ATM, None)
    _, _, a = run_steps(scene, 20)
    _, _, b = run_steps(dataclasses.replace(scene, ambient_pressure=0.0), 20)
    assert np.array_equal(np.asarray(a.x), np.asarray(b.x)) and np.array_equal(np.asarray(a.v), np.asarray(b.v))
    assert "ambient_pressure" not in scene_to_toml(scene)
    on = dataclasses.replace(scene, ambient_pressure=ATM)
    assert scene_from_toml(scene_to_toml(on)).ambient_pressure == ATM
    assert float(jaxmpm.default_params(on).ambient_pressure) == ATM
    for bad in (-1.0, float("nan"), float("inf"), "1 atm"):
        with pytest.raises(ValueError, match=r"effects\.ambient_pressure = .* allowed"):
            dataclasses.replace(scene, ambient_pressure=bad)
    with pytest.raises(ValueError, match=r"effects\.ambient_pressure = 101325\.0 is invalid: allowed unset"):
        dataclasses.replace(scene, ambient_pressure=ATM, c_h=0.1)
    params = dataclasses.replace(jaxmpm.default_params(on), ambient_pressure=jnp.asarray(-5.0))
    with pytest.raises(ValueError, match=r"params\.ambient_pressure = -5\.0 is invalid: allowed >= 0 Pa"):
        jaxmpm.model.params.check_params(on, params)
