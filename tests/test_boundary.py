"""Boundary conditions per face: a slip wall takes only normal momentum, a fixed wall takes all."""

import numpy as np
import pytest

import jaxmpm
from jaxmpm.model.scene import Boundary, Box, Grid, Phase, Scene

MAT = jaxmpm.Material.make("m", "linear_elastic", rho0=1000.0, E=1e6, nu=0.3)


def _run(kind, side="lo"):
    floor = (0.0, 0.3) if side == "lo" else (0.7, 1.0)
    scene = Scene(
        grid=Grid(cells=(20, 20), h=0.05),
        materials=(MAT,),
        phases=(Phase("block", "m", Box((0.3, floor[0]), (0.7, floor[1])), velocity=(2.0, 0.0)),),
        gravity=(0.0, -9.81 if side == "lo" else 9.81),
        boundary=Boundary(faces=((f"y_{side}", kind),)),
        t_end=0.05,
        n_out=1,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    final, _ = jaxmpm.simulate(scene, params, s0, progress=False)
    return scene, s0, final


@pytest.mark.parametrize("side", ["lo", "hi"])
def test_slip_wall_keeps_tangential_momentum_and_holds_the_block(side):
    scene, s0, final = _run("slip", side)
    p0, p1 = jaxmpm.diagnostics.momentum(s0), jaxmpm.diagnostics.momentum(final)
    np.testing.assert_allclose(float(p1[0]), float(p0[0]), rtol=1e-12)
    drop = abs(float(np.average(final.x[:, 1], weights=final.mass) - np.average(s0.x[:, 1], weights=s0.mass)))
    assert drop < 0.1 * 0.5 * 9.81 * 0.05**2  # held: the centre of mass moves < 10% of free fall
    wall, inward = (0.0, 1.0) if side == "lo" else (1.0, -1.0)
    assert np.all((np.asarray(final.x[:, 1]) - wall) * inward > 0.0)  # no particle on or past the wall


def test_fixed_wall_takes_tangential_momentum_free_face_does_not():
    _, s0, fixed = _run("fixed")
    _, _, free = _run("free")
    p0 = float(jaxmpm.diagnostics.momentum(s0)[0])
    assert float(jaxmpm.diagnostics.momentum(fixed)[0]) < 0.9 * p0
    np.testing.assert_allclose(float(jaxmpm.diagnostics.momentum(free)[0]), p0, rtol=1e-12)
