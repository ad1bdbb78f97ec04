"""2D axisymmetric (r, z) geometry (PHYSICS 2.3): volumes per radian, hoop stress and hoop rate,
the axis condition v_r = 0; checked against the exact radial vibration of an elastic cylinder."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxmpm
from jaxmpm.materials import library_material
from jaxmpm.model.scene import Boundary, Box, Grid, Phase, Scene, Sphere
from jaxmpm.model.state import phase_slices


def bessel_j(n, x):
    """J_n(x) = (1/pi) integral_0^pi cos(n tau - x sin tau) d tau (trapezoid, 4000 intervals)."""
    tau = np.linspace(0.0, np.pi, 4001)
    return np.trapezoid(np.cos(n * tau - np.atleast_1d(x)[:, None] * np.sin(tau)), tau, axis=1) / np.pi


def radial_mode(lam, mu, R):
    """Wavenumber k of the first radial mode u = J1(k r) of a solid cylinder with a free surface
    in plane strain: (lambda + 2 mu) u'(R) + lambda u(R) / R = 0 (bisection)."""
    f = lambda k: float(
        ((lam + 2 * mu) * k * (bessel_j(0, k * R) - bessel_j(1, k * R) / (k * R)) + lam * bessel_j(1, k * R) / R)[0]
    )
    lo, hi = 0.5 / R, 3.0 / R
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.sign(f(mid)) == np.sign(f(lo)) else (lo, mid)
    return 0.5 * (lo + hi)


def cylinder_frequency(cells, shape="ddmp", cfl=0.2):
    rho, E, nu, R = 1000.0, 1e7, 0.3, 1.0
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    k = radial_mode(lam, mu, R)
    omega = k * np.sqrt((lam + 2 * mu) / rho)
    h = R / cells
    mat = jaxmpm.Material.make("m", "hypoelastic", rho0=rho, E=E, nu=nu)
    scene = Scene(
        grid=Grid(cells=(cells + 2, 4), h=h),
        materials=(mat,),
        axisymmetric=True,
        shape=shape,
        phases=(Phase("cylinder", "m", Box((0.0, 0.0), (R, 4 * h))),),
        boundary=Boundary(faces=(("y_lo", "slip"), ("y_hi", "slip"))),  # uniform in z
        cfl=cfl,
        t_end=3 * np.pi / omega * 1.1,
        n_out=100,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    r = np.asarray(s0.x[:, 0])
    shape_r = jnp.asarray(bessel_j(1, k * r))
    s0 = dataclasses.replace(s0, v=jnp.stack([1e-4 * shape_r, jnp.zeros_like(shape_r)], -1))
    final, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    t = np.asarray(hist.t)
    amp = np.asarray(jnp.sum(s0.mass * hist.v[:, :, 0] * shape_r, axis=1))  # projection on the mode
    crossings = [
        t[i] - amp[i] * (t[i + 1] - t[i]) / (amp[i + 1] - amp[i])
        for i in range(len(t) - 1)
        if np.sign(amp[i]) != np.sign(amp[i + 1])
    ]
    e0 = float(jaxmpm.diagnostics.kinetic_energy(s0))
    energy = [
        float(jaxmpm.diagnostics.kinetic_energy(s) + jaxmpm.diagnostics.internal_energy(s))
        for s in (jax.tree.map(lambda a: a[i], hist) for i in range(len(t)))
    ]
    return np.pi / (crossings[1] - crossings[0]), omega, max(abs(e / e0 - 1) for e in energy)


def test_radial_vibration_of_a_cylinder_matches_the_bessel_frequency():
    """First radial mode, 20 and 40 cells across the radius (DDMP): frequency within 1e-3 of the
    exact one, second-order convergence. Kinetic + internal energy oscillates with the phase by an
    amount first order in dt and does not drift (1.0e-2 at CFL 0.2, 2.5e-3 at CFL 0.05, measured
    over 1.6 periods): the explicit update's, not the geometry's."""
    errors, drifts = [], []
    for cells in (20, 40):
        w, exact, de = cylinder_frequency(cells)
        errors.append(abs(w / exact - 1))
        drifts.append(de)
        assert de < 0.015
    assert errors[0] < 1e-3 and errors[1] < errors[0]
    assert np.log2(errors[0] / errors[1]) > 1.5, errors
    _, _, de_small_dt = cylinder_frequency(20, cfl=0.05)
    assert de_small_dt < 0.3 * drifts[0]


def test_axis_holds_v_r_zero_and_a_sphere_on_a_plate_conserves_mass_and_axial_momentum():
    """A coarse debris-cloud-like impact: al2024 sphere (full library model) on an al2024 plate at
    2 km/s with the closure; the nodes on the axis never move radially, mass is exact, the axial
    momentum is conserved (no wall acts along z) and kinetic + internal energy within 1%."""
    al = library_material("al2024")
    scene = Scene(
        grid=Grid(cells=(16, 28), h=0.5e-3),
        materials=(al,),
        axisymmetric=True,
        phases=(
            Phase("projectile", "al2024", Sphere((0.0, 0.0095), 0.003), velocity=(0.0, -2000.0)),
            Phase("plate", "al2024", Box((0.0, 0.004), (0.0075, 0.006))),
        ),
        c_h=0.15,
        artificial_viscosity=(0.5, 2.0),
        t_end=2e-6,
        n_out=2,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    final, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    assert all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(final))
    assert float(final.x[:, 0].min()) > 0.0
    np.testing.assert_array_equal(np.asarray(final.mass), np.asarray(s0.mass))
    pz0, pz1 = float(jaxmpm.diagnostics.momentum(s0)[1]), float(jaxmpm.diagnostics.momentum(final)[1])
    assert pz1 == pytest.approx(pz0, rel=1e-10)
    e0 = float(jaxmpm.diagnostics.kinetic_energy(s0))
    e1 = float(jaxmpm.diagnostics.kinetic_energy(final) + jaxmpm.diagnostics.internal_energy(final))
    assert abs(e1 / e0 - 1) < 0.01, e1 / e0 - 1
    assert float(final.eps_ps.max()) > 0.1  # it flowed plastically
    lay = jaxmpm.stages.layout.Layout.of(scene)
    assert np.all(lay.bc_mask.reshape(scene.grid.nodes + (2,))[0, :, 0] == 0.0)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(speed=0.0), r"speed = 0.0 is invalid: allowed a finite number > 0 m/s \(the impact speed"),
        (dict(speed=-6710.0), r"speed = -6710.0 is invalid"),
        (dict(plate_thickness=0.0), r"plate_thickness = 0.0 is invalid: allowed a finite number > 0"),
        (
            dict(gap=-1e-3),
            r"gap = -0.001 is invalid: allowed a finite number >= 0 m \(from the sphere to the plate's top face",
        ),
        (
            dict(resolution=0.5),
            r"resolution = 0.5 is invalid: allowed a finite number >= 0.724 \(4 cells across the plate\)",
        ),
        (dict(fields=3), r"fields = 3 is invalid: allowed 1 \| 2"),
    ],
)
def test_bad_debris_cloud_options(kw, match):
    with pytest.raises(ValueError, match=match):
        jaxmpm.load_scene("debris_cloud", **kw)


@pytest.mark.parametrize(
    "kw, match",
    [
        (
            dict(grid=Grid(cells=(4, 4, 4), h=0.1), phases=(Phase("b", "m", Box((0.1, 0.1, 0.1), (0.3, 0.3, 0.3))),)),
            r"axisymmetric = True is invalid: allowed only with a 2D \(r, z\) grid",
        ),
        (
            dict(grid=Grid(cells=(6, 4), h=0.1, origin=(-0.2, 0.0))),
            r"grid\.origin\[0\] = -0\.2 is invalid: allowed >= 0 m",
        ),
        (
            dict(shape="bspline2", transfer="apic"),
            r"axisymmetric = True is invalid: allowed only with shape 'ddmp' or 'linear'",
        ),
    ],
)
def test_bad_axisymmetric_scenes(kw, match):
    m = jaxmpm.Material.make("m", "hypoelastic", rho0=1000.0, E=1e6, nu=0.3)
    args = dict(
        grid=Grid(cells=(4, 4), h=0.1),
        materials=(m,),
        phases=(Phase("b", "m", Box((0.1, 0.1), (0.3, 0.3))),),
        axisymmetric=True,
    )
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        Scene(**args)


def test_axisymmetric_scene_file_round_trips_and_writes_per_radian_units(tmp_path):
    m = jaxmpm.Material.make("m", "hypoelastic", rho0=1000.0, E=1e6, nu=0.3)
    scene = Scene(
        grid=Grid(cells=(6, 6), h=0.1),
        materials=(m,),
        axisymmetric=True,
        t_end=1e-3,
        n_out=1,
        phases=(Phase("b", "m", Box((0.0, 0.1), (0.3, 0.3))),),
    )
    assert jaxmpm.io.scenefile.scene_from_toml(jaxmpm.scene_to_toml(scene)) == scene
    params = jaxmpm.default_params(scene)
    _, hist = jaxmpm.simulate(scene, params, jaxmpm.init_state(scene, params), progress=False)
    path, _ = jaxmpm.io.write(tmp_path / "run.h5", scene, hist, params)
    import h5py

    with h5py.File(path) as f:
        g = f["t0001"]["b"]
        assert g["volume"].attrs["units"] == "m^3/rad" and g["mass"].attrs["units"] == "kg/rad"
        assert g["stress"].shape[1:] == (3, 3)
    assert 'Name="stress_tt"' in (tmp_path / "run.xdmf").read_text()


def test_two_fields_with_the_closure_and_interface_forces_do_not_create_energy():
    """Sphere (field 0) on plate (field 1) at 2 km/s, weak drag, closure on: the fields interpenetrate
    and drag dissipates, so kinetic + internal energy may only fall. With the fragmented material's
    full pressure in the common pressure (E6) while its own stress force carries only alpha p (E8),
    this run gained 37% by 2 us; the common pressure now takes alpha p."""
    al = library_material("al2024")
    scene = Scene(
        grid=Grid(cells=(16, 28), h=0.5e-3),
        materials=(al,),
        axisymmetric=True,
        shape="linear",
        phases=(
            Phase("projectile", "al2024", Sphere((0.0, 0.0095), 0.003), velocity=(0.0, -2000.0), field=0),
            Phase("plate", "al2024", Box((0.0, 0.004), (0.0075, 0.006)), field=1),
        ),
        drag=1.0,
        c_h=0.15,
        artificial_viscosity=(0.5, 2.0),
        t_end=2e-6,
        n_out=4,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, progress=False)
    e = [
        float(jaxmpm.diagnostics.kinetic_energy(s) + jaxmpm.diagnostics.internal_energy(s))
        for s in (jax.tree.map(lambda a: a[i], hist) for i in range(len(hist.t)))
    ]
    assert max(e) <= e[0] * (1 + 1e-3), [x / e[0] - 1 for x in e]


@pytest.mark.slow
def test_debris_cloud_first_version_runs_and_conserves():
    """The built-in debris cloud (one field, coarsest resolution 0.75, 2 us): finite, mass exact, axial momentum
    conserved, kinetic + internal energy within 1% (its physics is not validated yet)."""
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    final, _ = jaxmpm.simulate(scene, params, s0, t_end=2e-6, n_out=1, progress=False)
    assert all(bool(jnp.isfinite(a).all()) for a in jax.tree.leaves(final))
    np.testing.assert_array_equal(np.asarray(final.mass), np.asarray(s0.mass))
    assert float(jaxmpm.diagnostics.momentum(final)[1]) == pytest.approx(
        float(jaxmpm.diagnostics.momentum(s0)[1]), rel=1e-10
    )
    e0 = float(jaxmpm.diagnostics.kinetic_energy(s0))
    e1 = float(jaxmpm.diagnostics.kinetic_energy(final) + jaxmpm.diagnostics.internal_energy(final))
    assert abs(e1 / e0 - 1) < 0.01


@pytest.fixture(scope="module")
def coarse_cloud():
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, t_end=3e-6, n_out=6, progress=False)
    return scene, params, s0, hist


def test_soft_feature_velocities_agree_with_the_hard_definitions(coarse_cloud):
    from jaxmpm import features

    scene, _, _, hist = coarse_cloud
    soft = np.asarray(features.feature_velocities(scene, hist, first=2))
    at = lambda k: jax.tree.map(lambda a: a[k], hist)
    hard = np.asarray(
        features.slope(
            hist.t[2:], jnp.stack([features.hard_feature_positions(scene, at(k)) for k in range(2, len(hist.t))])
        )
    )
    assert np.all(hard < -1000.0)  # all three move downstream
    np.testing.assert_allclose(soft, hard, rtol=0.02)
    # the soft positions lie inside the hard extremes by less than a cell
    for k in range(len(hist.t)):
        s, hd = (
            np.asarray(features.feature_positions(scene, at(k))),
            np.asarray(features.hard_feature_positions(scene, at(k))),
        )
        assert np.all(np.abs(s - hd) < scene.grid.h)


def test_feature_positions_have_finite_gradients_everywhere(coarse_cloud):
    from jaxmpm import features

    scene, _, _, hist = coarse_cloud
    state = jax.tree.map(lambda a: a[-1], hist)
    g = jax.jacrev(lambda x: features.feature_positions(scene, dataclasses.replace(state, x=x)))(state.x)
    assert np.isfinite(np.asarray(g)).all()
    assert np.all(np.abs(np.asarray(g)).sum(axis=(1, 2)) > 0.99)  # each feature is a weighted mean of z's


@pytest.mark.slow
def test_gradient_of_a_feature_velocity_with_respect_to_c_h_is_finite(coarse_cloud):
    from jaxmpm import features

    scene, params, s0, _ = coarse_cloud
    n = jaxmpm.plan_steps(scene, params, s0, 3e-6)

    def front_speed(c_h):
        _, h = jaxmpm.simulate(
            scene, dataclasses.replace(params, c_h=c_h), s0, t_end=3e-6, n_out=6, n_steps=n, checkpoint=True
        )
        return features.feature_velocities(scene, h, first=2)[0]

    g = jax.grad(front_speed)(jnp.asarray(0.15))
    assert np.isfinite(float(g))


@pytest.fixture(scope="module")
def point_velocity_gradients():
    """Two-field coarse cloud (C_d acts), 3 us, float64, at (C_d, C_h) = (1, 0.15): the Jacobian of
    the three point velocities (km/s) with respect to (log C_d, log C_h) by reverse mode through
    the checkpointed run, and central differences at steps 0.02, 0.005 and 1e-6."""
    from calibration.model import CloudModel

    model = CloudModel.build(resolution=0.75, fields=2, t_end=3e-6, n_out=6)
    theta = jnp.log(jnp.array([1.0, 0.15]))
    J = np.asarray(jax.jit(jax.jacrev(model.velocities))(theta))
    f = jax.jit(model.velocities)
    fd = {
        eps: np.stack(
            [(np.asarray(f(theta + eps * e)) - np.asarray(f(theta - eps * e))) / (2 * eps) for e in np.eye(2)], 1
        )
        for eps in (0.02, 0.005, 1e-6)
    }
    return J, fd


@pytest.mark.slow
def test_gradient_of_the_point_velocities_matches_small_step_differences(point_velocity_gradients):
    """The whole Jacobian of the three point velocities with respect to (log C_d, log C_h) by
    reverse mode through the checkpointed run, against central differences at step 1e-6: within
    1e-3 (the issue's bound was 5%; measured within 1e-4, e.g. d v_4 / d log C_d -0.012645 by AD and by
    differences, d v_1 / d log C_d -1.17886 and -1.17885). At this step the differences see the
    smooth piece AD differentiates; at steps of 1e-3 and more they also see the jumps of the
    response to C_d (the strict xfail below)."""
    J, fd = point_velocity_gradients
    np.testing.assert_allclose(J, fd[1e-6], rtol=1e-3)


@pytest.mark.slow
def test_gradient_of_the_projectile_rear_with_respect_to_c_h_matches_differences(point_velocity_gradients):
    """d v_4 / d log C_h (point 4, the rear of the projectile) by jax.grad within 5% of central
    differences at two steps (measured 8.86e-4 km/s by AD against 8.72e-4 and 8.85e-4)."""
    J, fd = point_velocity_gradients
    assert np.all(np.isfinite(J))
    for eps in (0.02, 0.005):
        assert J[2, 1] == pytest.approx(fd[eps][2, 1], rel=0.05), (eps, J[2, 1], fd[eps][2, 1])


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known limitation, documented in docs/limitations.md (issue 7): "
    "at steps of 0.02 and 0.005 in log C_d the differences cross "
    "jumps of v_4 (AD -0.0126 km/s against +0.0007 and -0.056): the response to the drag is smooth "
    "pieces about 1e-3 wide joined by particle-level switches the drag moves in time, e.g. a particle "
    "entering a cell whose far node has no other mass of its field (traced at step 72: that node's "
    "velocity enters the DDMP velocity gradient at once). At step 1e-6 AD matches (test above)",
)
def test_gradient_of_the_projectile_rear_with_respect_to_c_d_matches_differences(point_velocity_gradients):
    J, fd = point_velocity_gradients
    for eps in (0.02, 0.005):
        assert J[2, 0] == pytest.approx(fd[eps][2, 0], rel=0.05), (eps, J[2, 0], fd[eps][2, 0])


def sphere_on_plate(dim: int, t_end: float = 0.55e-6):
    """The debris cloud's impact (al2024 sphere of 9.53 mm at 6.71 km/s on a 2.21 mm plate), the
    hydrodynamic model (Mie-Grueneisen, no strength, no closure), viscosity (0.5, 2.0), cells of
    0.4 mm: axisymmetric (dim 2) or in 3D on a quarter of the domain, cut by the slip walls x = 0
    and y = 0 (its mirror planes). The sphere's upper half, whose release reaches the contact after
    t_end, is left out. -> (scene, params, initial state, index of the plate's rear-face particle
    nearest the axis)."""
    from jaxmpm.model.geometry import Difference

    R, T, V, h = 9.53e-3 / 2, 2.21e-3, 6710.0, 0.4e-3
    lateral, z_lo, z_hi = 7.2e-3, -(T + 2.4e-3), R + h + 1.2e-3
    nz, nw = round((z_hi - z_lo) / h), round(lateral / h)
    zero = (0.0,) * (dim - 1)
    sphere = Difference(Sphere(zero + (R + h,), R), (Box(tuple(-lateral for _ in zero) + (R + h,), (lateral,) * dim),))
    plate = Box(zero + (-T,), (6.4e-3,) * (dim - 1) + (0.0,))
    faces = ("x_hi", "y_lo", "y_hi") if dim == 2 else ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi")
    scene = Scene(
        grid=Grid(cells=(nw,) * (dim - 1) + (nz,), h=h, origin=zero + (z_lo,)),
        axisymmetric=dim == 2,
        materials=(library_material("al2024", model="mie_gruneisen"),),
        boundary=Boundary(faces=tuple((f, "slip") for f in faces)),
        phases=(
            Phase("projectile", "al2024", sphere, velocity=zero + (-V,)),
            Phase("plate", "al2024", plate),
        ),
        artificial_viscosity=(0.5, 2.0),
        t_end=t_end,
        n_out=round(t_end / 0.025e-6),
        cfl=0.3,
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    x = np.asarray(s0.x)
    plate_particles = phase_slices(scene)[1]
    r = np.linalg.norm(x[:, :-1], axis=1)
    axis = np.arange(len(x))[plate_particles][r[plate_particles] < h / 2]
    return scene, params, s0, int(axis[np.argmin(x[axis, -1])])


def test_a_sphere_on_a_plate_in_axisymmetry_matches_the_same_impact_in_3d():
    """The plate's rear face on the axis, where the debris cloud's front (point 1) is launched: the
    axisymmetric scheme (hoop stress and rate, the axis condition) against 3D on the same cells.
    Measured (801 and 18,398 particles): the face's velocity peaks at 5.59 km/s (axisymmetric) and
    5.69 km/s (3D), 0.50-0.53 us after the contact; its mean over the 0.3 us after it first exceeds
    1 km/s is 4.19 and 4.23 km/s. (The 1D plate's face of the same impact peaks at 7.4-7.6 km/s: the
    sphere's on-axis shock has decayed by the rear face in both; docs/closure.md.)"""
    measures = []
    for dim in (2, 3):
        scene, params, s0, rear = sphere_on_plate(dim)
        _, hist = jaxmpm.simulate(scene, params, s0, progress=False)
        t = np.asarray(hist.t)
        vz = -np.asarray(hist.v[:, rear, -1])
        z = -np.asarray(hist.x[:, rear, -1])
        k = int(np.argmax(vz > 1e3))
        window = (t >= t[k]) & (t <= t[k] + 0.3e-6 + 1e-12)
        measures.append((vz.max(), np.polyfit(t[window], z[window], 1)[0], t[k]))
    (peak2, mean2, start2), (peak3, mean3, start3) = measures
    assert abs(start2 - start3) < 1e-12  # the shock reaches the face at the same output
    assert abs(peak2 / peak3 - 1) < 0.05, (peak2, peak3)
    assert abs(mean2 / mean3 - 1) < 0.05, (mean2, mean3)
    assert 4.0e3 < mean3 < 5.0e3 and peak3 < 6.0e3  # the decayed shock (1D: 7.4-7.6 km/s peak)
