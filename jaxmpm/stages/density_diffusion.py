"""The fluids' density diffusion (stage 4, 'musl' update with DDMP): the delta-SPH density
diffusion term on the grid, a volume rate that relaxes each barotropic fluid particle's specific
volume toward its phase's local average."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.materials.models import split_model
from jaxmpm.model.params import Params
from jaxmpm.model.scene import is_fluid
from jaxmpm.model.state import State
from jaxmpm.numerics.shapes import Stencil
from jaxmpm.numerics.transfer import interpolate, scatter
from jaxmpm.stages import fields
from jaxmpm.stages.layout import Layout
from jaxmpm.stages.phase_models import bulk_modulus_and_wave_speed

BAROTROPIC = ("linear_fluid", "tait", "linear")  # fluid models, and equations of state, whose p depends on rho alone


def diffused_particles(layout: Layout) -> np.ndarray | None:
    """(N,) static bool: the particles of the barotropic fluid phases (`is_fluid`, the model
    or its equation of state in BAROTROPIC), which take the density diffusion with DDMP and the
    'musl' update (not with the closure, E4, whose volume rate is its own), or None where no
    particle does. DDMP's blend is what gives the particles of a cell different volume rates
    (`density_diffusion_rate`). An equation of state with an energy term is left out: its contact
    discontinuities (density jumps at one pressure) are not to be smoothed. None too where the
    scene's `density_diffusion` is 0."""
    scene = layout.scene

    def barotropic(model):
        return is_fluid(model) and (model in BAROTROPIC or split_model(model)[0] in BAROTROPIC)

    if scene.shape != "ddmp" or scene.transfer != "musl" or scene.has_closure or scene.density_diffusion == 0:
        return None
    on = [barotropic(scene.material(p).model) for p in scene.phases]
    if not any(on):
        return None
    return np.concatenate([np.full(sl.stop - sl.start, o, bool) for o, sl in zip(on, layout.slices)])


def phase_average(layout: Layout, stencils: Stencil, volume: jax.Array, q: jax.Array) -> jax.Array:
    """The volume-weighted nodal average of q (N,) over the particles of each phase, interpolated
    back to the phase's particles: sum_n S_n(x_p) (sum_q V_q q_q S_nq) / (sum_q V_q S_nq), the sums
    over the particles q of p's phase, in q's units. Exact for a linear q inside a phase; one-sided
    at its boundary nodes (a free surface, an interface). The linear fit of E15 in its place,
    exact there too, made the dam break non-finite within 300 steps: at nearly empty surface
    nodes the fit extrapolates."""
    g = layout.particle_sum(
        scatter(
            stencils,
            layout.phase,
            stencils.w[..., None] * jnp.stack([volume * q, volume], -1)[:, None, :],
            layout.n_phases,
            layout.n_nodes,
        )
    )
    q_n = fields.safe_div(g[..., :1], g[..., 1:], 1e-30 * layout.particle_max(volume))
    return interpolate(stencils, layout.phase, q_n)[:, 0]


def density_diffusion_rate(
    layout: Layout, params: Params, stencils: Stencil, state: State, fluid: np.ndarray
) -> jax.Array:
    """(N,) 1/s: the volume rate that relaxes each fluid particle's specific volume u = V / m to
    its phase's local average u-bar (`phase_average`) at the rate delta c / h, c the particle's sound
    speed and delta the scene's `density_diffusion`: (delta c / h) (u-bar / u - 1); 0 for the other particles. The density diffusion of
    delta-SPH on the grid. A weakly compressible fluid's pressure is K times its volume strain, and
    the grid sees a particle's volume only through its nodes' sums: volume errors that differ from
    particle to particle within a cell (DDMP's blend gives particles of one cell different volume
    rates where the flow is not linear) grow unchecked and show as pressure noise. The diffusion
    damps them at the grid scale within a few h / c and leaves a linear field of u (a fluid at rest
    under gravity) unchanged away from the phase's boundaries."""
    u = state.volume / state.mass
    u_bar = phase_average(layout, stencils, state.volume, u)
    c = bulk_modulus_and_wave_speed(layout, params, state)[1]
    rate = layout.scene.density_diffusion * c / layout.scene.grid.h * (u_bar / u - 1)
    return jnp.where(jnp.asarray(fluid), rate, 0.0)
