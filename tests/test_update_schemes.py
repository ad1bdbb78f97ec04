"""The update schemes on a single-field impact in a moving frame: energy must not be created.

Two equal 1D elastic blocks (aluminium-like: rho 2700 kg/m^3, E 70 GPa) meet at +150 and -50 m/s
in one velocity field. One field cannot separate them, so the collision is partly inelastic: the
total energy may fall, it must not rise. The 'seed' remap at the new positions creates energy at
the contact; the default 'musl' remap does not. Momentum is exact in both.
"""

import jax
import numpy as np

import jaxmpm
from jaxmpm.model.scene import Box, Grid, Phase, Scene

AL = jaxmpm.Material.make("al", "linear_elastic", rho0=2700.0, E=70e9, nu=0.0)


def impact(transfer, cells=200, cfl=0.3):
    scene = Scene(
        grid=Grid(cells=(cells,), h=0.4 / cells),
        materials=(AL,),
        transfer=transfer,
        cfl=cfl,
        phases=(
            Phase("a", "al", Box((0.098,), (0.198,)), velocity=(150.0,)),
            Phase("b", "al", Box((0.202,), (0.302,)), velocity=(-50.0,)),
        ),
        t_end=80e-6,
        n_out=20,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    frames = [jax.tree.map(lambda a: a[i], hist) for i in range(len(hist.t))]
    E = np.array([float(jaxmpm.diagnostics.total_energy(scene, params, f)) for f in frames])
    P = np.array([float(jaxmpm.diagnostics.momentum(f)[0]) for f in frames])
    return E / E[0] - 1, P


def test_musl_does_not_create_energy_at_a_contact_seed_does():
    e_musl, p_musl = impact("musl")
    e_seed, p_seed = impact("seed")
    print(f"energy change: musl max {e_musl.max():+.4f} end {e_musl[-1]:+.4f}; seed max {e_seed.max():+.4f}")
    assert e_musl.max() < 0.01  # at most a transient at first contact (measured +0.2%)
    assert e_musl[-1] > -0.15  # the inelastic loss of one field stays moderate
    assert e_seed.max() > 0.05  # the new-position remap gains energy at this CFL
    for p in (p_musl, p_seed):
        np.testing.assert_allclose(p, p[0], rtol=1e-12)
