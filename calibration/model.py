"""The forward model: debris-cloud parameters -> the three feature velocities (km/s).

theta = (log C_d, log C_h): both are positive, and their effects span decades, so the fit works
in log space. `CloudModel.velocities(theta)` runs the fixed-length, checkpointed `simulate`
(checkpoint="auto": each step recomputed once in reverse while the stored states take at most
1 GiB, nested checkpointing beyond) and measures the features of
`jaxmpm.features` over the later half of the outputs (after the cloud has formed).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

import jaxmpm
from jaxmpm import features
from jaxmpm.model.params import Params
from jaxmpm.model.scene import Scene
from jaxmpm.model.state import State

COARSE_RESOLUTION = 0.75  # the coarsest with >= 4 cells across the plate


@dataclass(frozen=True)
class CloudModel:
    scene: Scene
    params: Params  # at the scene's defaults (C_d, C_h replaced by theta)
    state: State  # initial
    n_steps: int
    t_end: float
    n_out: int = 12
    first: int = 6  # first output of the velocity fit (the later half)

    @staticmethod
    def build(
        resolution: float = COARSE_RESOLUTION,
        fields: int = 2,
        t_end: float = 6e-6,
        n_out: int = 12,
        max_c_h: float = 1.0,
        safety: float = 2.0,
        **scene_options: Any,
    ) -> CloudModel:
        """The debris cloud at `resolution` with `fields` velocity fields (2: projectile and plate
        apart, so C_d acts). Steps: `safety` times the initial CFL estimate at C_h = max_c_h (the
        step shrinks as the cloud heats: at resolution 0.75, C_h = 1 needs ~1.6x; steps past
        t_end have zero length)."""
        scene = jaxmpm.load_scene("debris_cloud", resolution=resolution, fields=fields, t_end=t_end, **scene_options)
        params = jaxmpm.default_params(scene)
        state = jaxmpm.init_state(scene, params)
        n_steps = jaxmpm.plan_steps(
            scene, dataclasses.replace(params, c_h=jnp.asarray(max_c_h, params.c_h.dtype)), state, t_end, safety=safety
        )
        return CloudModel(scene, params, state, n_steps, float(t_end), n_out, n_out // 2)

    def with_theta(self, theta: ArrayLike) -> Params:
        """Params with C_d = exp(theta[0]) (with one field, no drag: ignored) and C_h = exp(theta[1]);
        theta (2,)."""
        theta = jnp.asarray(theta, self.params.c_h.dtype)
        new = dict(c_h=jnp.exp(theta[1]))
        if self.scene.drag is not None:
            new["drag"] = jnp.exp(theta[0])
        return dataclasses.replace(self.params, **new)

    def velocities_of_history(self, history: State) -> jax.Array:
        """(3,) km/s, downstream positive, of points 1, 2, 4 from a history (a State with a leading
        time axis of n_out + 1)."""
        return -features.feature_velocities(self.scene, history, first=self.first) / 1000.0

    def run(self, theta: ArrayLike, **options: Any) -> tuple[State, State]:
        """(final, history) of the fixed-length run at theta = (log C_d, log C_h), allowed to fall
        short of t_end (see `reached`); options: simulate's checkpoint, progress."""
        return jaxmpm.simulate(
            self.scene,
            self.with_theta(theta),
            self.state,
            t_end=self.t_end,
            n_out=self.n_out,
            n_steps=self.n_steps,
            allow_short=True,
            **options,
        )

    def velocities(self, theta: ArrayLike, checkpoint: bool | str | None = "auto") -> jax.Array:
        """(3,) km/s of points 1, 2, 4 at theta = (log C_d, log C_h). Differentiable."""
        return self.velocities_of_history(self.run(theta, checkpoint=checkpoint)[1])

    def plate_lead_of_history(self, history: State) -> jax.Array:
        """How far (m) the plate's material leads the projectile's at the last output
        (`jaxmpm.features.plate_lead`; negative: projectile material has passed through the plate's debris)."""
        return features.plate_lead(self.scene, jax.tree.map(lambda a: a[-1], history))

    def reached(self, theta: ArrayLike, progress: bool = True) -> float:
        """The time (s) a run at theta reaches in n_steps (it falls short of t_end where the CFL
        step collapses): check it outside jax.grad, where `velocities` cannot."""
        return self.checks(theta, progress)[0]

    def checks(self, theta: ArrayLike, progress: bool = True) -> tuple[float, float]:
        """(time reached (s), plate lead (m)) of one run at theta: the checks a fit's result needs
        beside its velocities (`reached`, `plate_lead_of_history`)."""
        final, history = self.run(theta, progress=progress)
        return float(final.t), float(self.plate_lead_of_history(history))

    def velocities_batch(self, thetas: ArrayLike, allow_short: bool = False, progress: bool = True) -> jax.Array:
        """(B, 3) km/s for a batch of theta (B, 2), in one vmapped call (`jaxmpm.ensemble`); with
        allow_short, members that do not reach t_end give NaN instead of an error."""
        return self.table_batch(thetas, allow_short, progress)[0]

    def table_batch(
        self, thetas: ArrayLike, allow_short: bool = False, progress: bool = True
    ) -> tuple[jax.Array, jax.Array]:
        """((B, 3) km/s, (B,) m): `velocities_batch`'s velocities and each member's
        `plate_lead_of_history`, from the same vmapped call."""
        thetas = np.asarray(thetas, dtype=float)
        values = dict(c_h=np.exp(thetas[:, 1]))
        if self.scene.drag is not None:
            values["drag"] = np.exp(thetas[:, 0])
        batch = jaxmpm.batch.sweep(self.params, **values)
        final, history = jaxmpm.ensemble(
            self.scene,
            batch,
            self.state,
            t_end=self.t_end,
            n_out=self.n_out,
            n_steps=self.n_steps,
            allow_short=allow_short,
            progress=progress,
        )
        velocities = jax.vmap(self.velocities_of_history)(history)
        short = final.t < self.t_end * (1 - 1e-6)
        leads = jax.vmap(self.plate_lead_of_history)(history)
        return jnp.where(short[:, None], jnp.nan, velocities), jnp.where(short, jnp.nan, leads)


def through_plate_warning(labels: Sequence[Any], lead: ArrayLike, prefix: str = "") -> str:
    """A line on the cloud's structure: the members whose projectile has passed through the plate's
    debris (lead < 0; `jaxmpm.features.plate_lead`), or that none has."""
    through = [
        f"{prefix}{x:g}" if isinstance(x, float | int) else f"{prefix}{x}" for x, li in zip(labels, lead) if li < 0
    ]
    if not through:
        return "plate lead > 0 in every run: the plate's debris leads the cloud, as in the experiment"
    return (
        f"warning: at {', '.join(through)} projectile material has passed through the plate's debris "
        "(plate lead < 0): the exchange drag is too weak to hold it, point 1 is projectile material, and the "
        "cloud's structure is not the experiment's (the plate's debris ahead)"
    )


def theta_of(c_d: float, c_h: float) -> np.ndarray:
    """theta = (log C_d, log C_h) (2,) of C_d > 0 and C_h > 0."""
    if not (c_d > 0 and c_h > 0):
        raise ValueError(f"C_d = {c_d!r}, C_h = {c_h!r} are invalid: allowed > 0 both (the fit works in log space)")
    return np.log([float(c_d), float(c_h)])
