"""A small two-phase scene on which C_d and C_h are both identifiable: the synthetic-recovery
check of the fit (generate "measurements" at known (C_d, C_h), start away, recover them).

Scene (1D, closed box of 12 mm, 48 cells, fixed walls; two velocity fields): a fragmented Al-2024
block (library `al2024`, 4 mm wide, volume fraction 0.4, pre-compressed to J = 0.99, i.e.
p ~ 0.79 GPa, plastic strain eps_ps = 0.05) moves at 300 m/s through water (library `water`, the
rest of the volume, at rest) in its own field. The scene counts plastic strain as fragmentation
(fragmentation = 'plastic', the seed's E5), so the unfailed block is fragmented by its eps_ps. The
exchange drag (E3, C_d) slows the block; the closure (E4, E5, E8; alpha = 1 - tanh(eps_ps / C_h))
sets how fast the block's pressure relaxes toward the water's: E4's B = (1 - alpha)(p - p_amb) /
(K tau), tau = h / c ~ 47 ns here, so the pressure falls within a few tau at a rate that C_h sets.

Observables (all smooth in theta = (log C_d, log C_h)):
  0  the block's mean velocity at t_end = 4 us, in 100 m/s        (C_d: the drag's work)
  1  the block's mass-weighted spread (std of x) at t_end, mm
  2  the block's mass-weighted mean pressure at t_end / 40 = 0.1 us, GPa   (C_h: the relaxation)
At (C_d, C_h) = (1, 0.15): 1.258, 1.153, 0.325; Jacobian rows (-0.419, -0.0032), (-2.8e-4, 1.5e-3),
(1.6e-3, 0.196): condition of J^T J 4.6, both parameters identifiable. At t_end the relaxation is long over, so the late
observables hardly see C_h (d spread / d log C_h = 1.5e-3 mm); the early pressure does (0.127,
0.325, 0.443 GPa at C_h = 0.05, 0.15, 0.3) and hardly sees C_d (0.326 at C_d = 2).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

import jaxmpm
from jaxmpm.materials import library_material
from jaxmpm.model.params import Params
from jaxmpm.model.scene import Boundary, Box, Grid, Phase, Scene
from jaxmpm.model.state import State

CELLS, H = 48, 0.25e-3  # 12 mm box
J0, EPS_PS0, SPEED = 0.99, 0.05, 300.0
N_OUT, EARLY = 40, 1  # outputs over t_end; the early pressure is read at output EARLY (t_end / 40)


def debris_in_water(drag: float = 1.0, c_h: float = 0.15, t_end: float = 4e-6) -> Scene:
    """The scene of the module docstring (phases: debris in field 0; water in field 1)."""
    water_box = lambda a, b: Box((a,), (b,))
    return Scene(
        name="debris_in_water",
        description="fragmented Al-2024 block moving through water (1D, two fields)",
        grid=Grid(cells=(CELLS,), h=H),
        materials=(library_material("al2024"), library_material("water")),
        boundary=Boundary(faces=(("x_lo", "fixed"), ("x_hi", "fixed"))),
        phases=(
            Phase("debris", "al2024", water_box(4e-3, 8e-3), velocity=(SPEED,), field=0, fraction=0.4),
            Phase("water_in", "water", water_box(4e-3, 8e-3), field=1, fraction=0.6),
            Phase("water_lo", "water", water_box(0.0, 4e-3), field=1),
            Phase("water_hi", "water", water_box(8e-3, CELLS * H), field=1),
        ),
        drag=drag,
        c_h=c_h,
        fragmentation="plastic",
        t_end=t_end,
        n_out=4,
        cfl=0.3,
    )


def fragmented_precompressed(scene: Scene, params: Params, state: State) -> State:
    """The debris block at J0 (volume and F scaled; p = K0 (1 - J0) with K0 = rho0 c0^2 of the
    Mie-Grueneisen EOS, stress -p I) with plastic strain EPS_PS0, so alpha = 1 - tanh(EPS_PS0 / C_h)."""
    block = jaxmpm.model.state.phase_slices(scene)[0]
    debris = params.phases["debris"]
    p0 = debris["rho0"] * debris["c0"] ** 2 * (1 - J0)
    dims = state.x.shape[1]
    return dataclasses.replace(
        state,
        volume=state.volume.at[block].multiply(J0),
        F=state.F.at[block].multiply(J0 ** (1 / dims)),
        stress=state.stress.at[block].set(-p0 * jnp.eye(dims, dtype=state.stress.dtype)),
        pressure=state.pressure.at[block].set(p0),
        eps_ps=state.eps_ps.at[block].set(EPS_PS0),
    )


@dataclass(frozen=True)
class DebrisInWaterModel:
    """The debris_in_water scene, its default Params, its pre-compressed initial State and the
    scan steps that reach t_end."""

    scene: Scene
    params: Params
    state: State
    n_steps: int

    @staticmethod
    def build(t_end: float = 4e-6, safety: float = 1.5) -> DebrisInWaterModel:
        """The model at the default (C_d, C_h), with `safety` times the initial CFL estimate of steps."""
        scene = debris_in_water(t_end=t_end)
        params = jaxmpm.default_params(scene)
        state = fragmented_precompressed(scene, params, jaxmpm.init_state(scene, params))
        return DebrisInWaterModel(scene, params, state, jaxmpm.plan_steps(scene, params, state, t_end, safety=safety))

    def with_theta(self, theta: ArrayLike) -> Params:
        """Params with C_d = exp(theta[0]) and C_h = exp(theta[1]); theta (2,)."""
        theta = jnp.asarray(theta, self.params.c_h.dtype)
        return dataclasses.replace(self.params, drag=jnp.exp(theta[0]), c_h=jnp.exp(theta[1]))

    def run(self, theta: ArrayLike) -> tuple[State, State]:
        """The State at t_end and the history (N_OUT outputs, the k-th at k t_end / N_OUT) of the run at
        theta = (log C_d, log C_h)."""
        return jaxmpm.simulate(
            self.scene,
            self.with_theta(theta),
            self.state,
            t_end=self.scene.t_end,
            n_out=N_OUT,
            n_steps=self.n_steps,
            checkpoint="auto",
        )

    def observables(self, theta: ArrayLike) -> jax.Array:
        """(3,) the observables of the module docstring at theta = (log C_d, log C_h). Differentiable."""
        final, history = self.run(theta)
        block = jaxmpm.model.state.phase_slices(self.scene)[0]
        m, x, v = final.mass[block], final.x[block, 0], final.v[block, 0]  # (N_block,) kg, m, m/s
        mass = jnp.sum(m)
        centre = jnp.sum(m * x) / mass
        spread = jnp.sqrt(jnp.sum(m * (x - centre) ** 2) / mass)
        early = jnp.sum(history.mass[EARLY, block] * history.pressure[EARLY, block]) / jnp.sum(
            history.mass[EARLY, block]
        )
        return jnp.stack([jnp.sum(m * v) / mass / 100.0, spread * 1e3, early / 1e9])
