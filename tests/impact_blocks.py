"""Two equal 1D aluminium blocks meeting in a moving frame: the impact of the multiphase grouping
and continuity tests."""

import jax
import numpy as np

import jaxmpm
from jaxmpm.model.scene import Box, Grid, Phase, Scene
from jaxmpm.model.state import phase_slices

AL = jaxmpm.Material.make("al", "linear_elastic", rho0=2700.0, E=70e9, nu=0.0)
PLATEAU = 2700.0 * (70e9 / 2700.0) ** 0.5 * 100.0  # rho c dv / 2, Pa: the exact contact stress (1.375 GPa)


def two_blocks(drag, continuity, cells=400, fields=2, t_end=80e-6, n_out=80):
    """Two equal 1D aluminium blocks (100 mm, 4 mm apart) meeting at +150 and -50 m/s (a moving
    frame: momentum errors show), in one field or in two coupled by C_d = drag."""
    kw = dict(drag=drag, continuity=continuity) if fields == 2 else {}
    return Scene(
        grid=Grid(cells=(cells,), h=0.4 / cells),
        materials=(AL,),
        phases=(
            Phase("a", "al", Box((0.098,), (0.198,)), velocity=(150.0,), field=0),
            Phase("b", "al", Box((0.202,), (0.302,)), velocity=(-50.0,), field=fields - 1),
        ),
        t_end=t_end,
        n_out=n_out,
        **kw,
    )


def run_blocks(scene):
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    frames = [jax.tree.map(lambda a: a[i], hist) for i in range(len(hist.t))]
    E = np.array([float(jaxmpm.diagnostics.total_energy(scene, params, f)) for f in frames])
    P = np.array([float(jaxmpm.diagnostics.momentum(f)[0]) for f in frames])
    a, b = phase_slices(scene)
    gap = np.array([float(f.x[b, 0].min() - f.x[a, 0].max()) for f in frames])  # > 0: apart
    va = np.array([float(f.v[a, 0].mean()) for f in frames])
    vb = np.array([float(f.v[b, 0].mean()) for f in frames])
    return hist, E, P, gap, va, vb


def contact_stress(hist, scene):
    """(n_out,) compressive stress (Pa) of the 4 particles nearest the contact point (the middle
    between the blocks' facing ends) at each output."""
    a, b = phase_slices(scene)
    x = np.asarray(hist.x[:, :, 0])
    sxx = np.asarray(hist.stress[:, :, 0, 0])
    mid = 0.5 * (x[:, a].max(1) + x[:, b].min(1))
    near = np.argsort(np.abs(x - mid[:, None]), axis=1)[:, :4]
    return -np.take_along_axis(sxx, near, 1).mean(1)
