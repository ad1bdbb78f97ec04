"""Exact references for the multi-field pressure and the water / concrete material models:
the common pressure (E6) and the ambient pressure of the closure (E8) against their formulas
evaluated by hand, the pressure-moment fit (E15) on linear pressure fields, the stiffened-gas and
Tait equations of state of the library's water against their closed forms (pressure, sound speed,
isentrope, and a measured pulse speed), and the Drucker-Prager strength of the library's concrete
against its yield surface Y(p) = clip(Y0 + dY_dp p, 0, Ymax) on single-point strain paths.
Every reference here is computed in the test from the formula, in float64; none is a value
recorded from a run of the code."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

import jaxmpm  # noqa: E402 (after float64 is on)
from jaxmpm.numerics import shapes, transfer  # noqa: E402
from jaxmpm.stages import fields  # noqa: E402
from jaxmpm.materials import library_material, model_of  # noqa: E402
from jaxmpm.materials.hydro import eos_coefficients  # noqa: E402
from jaxmpm.model.scene import Grid  # noqa: E402

from test_material_models import drive, pulse_speed  # noqa: E402


def constants(material):
    return {k: jnp.asarray(v) for k, v in material.constants}


# ------------------------------------------------------------------ E6, E8: common pressure
# Three fields at four nodes, compressibilities kappa = 1 / K of air (K = gamma p at 1 atm), water
# (Saurel-Abgrall stiffened gas at rest: K = gamma (p0 + p_inf)) and steel (K = 160 GPa).
KAPPA = np.array([1 / (1.4 * 101325.0), 1 / (4.4 * (101325.0 + 6e8)), 1 / 160e9])
# node 0: all three fields; node 1: air and water; node 2: water and steel; node 3: water alone
THETA = np.array([[0.2, 0.5, 0.0, 0.0], [0.3, 0.5, 0.6, 0.9], [0.5, 0.0, 0.4, 0.0]])
P = np.array(
    [
        [2.0e5, 1.0e5, 7.0e15, -3.0e15],  # absent fields (theta = 0) hold absurd pressures:
        [3.0e6, 1.0e6, 2.0e8, 5.0e7],  # they must have no say
        [-4.0e7, 9.0e15, 1.0e9, 8.0e15],
    ]
)


def hand_common_pressure(theta, kappa, p, fields_present):
    """sum_i theta_i kappa_i p_i / sum_j theta_j kappa_j over the listed fields, one node, in plain Python."""
    num = sum(theta[i] * kappa[i] * p[i] for i in fields_present)
    den = sum(theta[i] * kappa[i] for i in fields_present)
    return num / den


def test_e6_common_pressure_weights_each_field_by_theta_times_compressibility():
    """(E6) p = sum_i f_i p_i, f_i = theta_i kappa_i / sum_j theta_j kappa_j, against the formula
    evaluated by hand at each node over the fields present there (three fields; two; one). A field
    absent at a node (theta = 0) has no say whatever pressure it holds; a lone field gives its own
    pressure; the softest field present dominates (air beside water: p within kappa_w / kappa_a =
    6e-5 of the air's pressure; water beside steel: within 2% of the water's)."""
    kappa = np.repeat(KAPPA[:, None], THETA.shape[1], 1)
    p = np.asarray(fields.common_pressure(jnp.asarray(THETA), jnp.asarray(kappa), jnp.asarray(P)))
    present = [(0, 1, 2), (0, 1), (1, 2), (1,)]
    expected = [hand_common_pressure(THETA[:, n], KAPPA, P[:, n], f) for n, f in enumerate(present)]
    np.testing.assert_allclose(p, expected, rtol=1e-13)
    assert p[3] == pytest.approx(P[1, 3], rel=1e-15)  # a lone field: its own pressure
    assert abs(p[1] - P[0, 1]) < 1e-4 * abs(P[1, 1] - P[0, 1])  # air beside water: the air's
    assert abs(p[2] - P[1, 2]) < 0.02 * abs(P[2, 2] - P[1, 2])  # water beside steel: the water's


def test_e8_ambient_pressure_is_the_common_pressure_of_the_other_groups():
    """(E8) p_amb,k = the common pressure (E6) of the groups (phases, or fields of one phase each)
    other than k, by hand at each node, and 0 where no other group is present ('0 in vacuum'): the
    lone water at node 3, and at the water's node 3 itself; absent groups (theta = 0) have no say."""
    kappa = np.repeat(KAPPA[:, None], THETA.shape[1], 1)
    amb = np.asarray(fields.ambient_pressure(jnp.asarray(THETA), jnp.asarray(kappa), jnp.asarray(P)))
    assert amb.shape == THETA.shape
    for n in range(THETA.shape[1]):
        for k in range(3):
            others = [i for i in range(3) if i != k and THETA[i, n] > 0]
            expected = hand_common_pressure(THETA[:, n], KAPPA, P[:, n], others) if others else 0.0
            assert amb[k, n] == pytest.approx(expected, rel=1e-12, abs=0.0), (k, n)
    assert amb[1, 3] == 0.0  # water alone: vacuum around it


@pytest.mark.parametrize("continuity", ["off", "transport"])
def test_e8_ambient_pressure_does_not_depend_on_how_the_phases_are_grouped_into_fields(continuity):
    """(E8) names the other PHASES. A rock block, half inside a gas layer and with a corner in a
    water pool, random particle pressures. The ambient pressure at every particle is the one the
    grid update forms from the interface forces' per-field nodal quantities with each phase in a
    field of its own, and the per-phase scatter gives the same: with gas and water sharing a field
    (interface forces on), and where both use E15's fit (continuity 'off'; 'transport' estimates
    the nodal pressures as V S-weighted averages instead) with all three in one field and with
    three fields coupled by drag alone. Not 0 inside the gas or the water, 0 where the rock's nodes
    hold no other phase."""
    import dataclasses

    from jaxmpm.stages.multifield import ambient_pressure_by_phase
    from jaxmpm.model.scene import Box, Phase, Scene
    from jaxmpm.numerics.shapes import ddmp_beta, stencil
    from jaxmpm.stages.layout import Layout
    from jaxmpm.step import _mass_floor, grid_acceleration, particle_to_grid

    rock = jaxmpm.Material.make("rock", "hypoelastic", rho0=2000.0, E=2.0e9, nu=0.25)
    gas = jaxmpm.Material.make("gas", "linear_fluid", rho0=10.0, K=1.0e7)
    water = jaxmpm.Material.make("water", "linear_fluid", rho0=1000.0, K=2.2e9)

    def scene(fields, interface_forces=True):
        coupled = len(set(fields)) > 1
        return Scene(
            grid=Grid(cells=(12, 12), h=0.1),
            materials=(rock, gas, water),
            c_h=0.01,
            continuity=continuity if coupled and interface_forces else "off",
            interface_forces=interface_forces if coupled else False,
            phases=(
                Phase("rock", "rock", Box((0.3, 0.3), (0.7, 0.7)), field=fields[0], fraction=0.6),
                Phase("gas", "gas", Box((0.2, 0.5), (1.0, 0.9)), field=fields[1], fraction=0.4),
                Phase("water", "water", Box((0.0, 0.0), (0.5, 0.4)), field=fields[2], fraction=0.3),
            ),
            drag=1.0 if coupled else None,
        )

    three = scene((0, 1, 2))
    others = {"gas and water in one field": scene((0, 1, 1))}
    if continuity == "off":
        others.update({"one field": scene((0, 0, 0)), "drag alone": scene((0, 1, 2), interface_forces=False)})
    lay3 = Layout.of(three)
    assert lay3.ambient_by_field and not any(Layout.of(sc).ambient_by_field for sc in others.values())
    params = jaxmpm.default_params(three)
    s = jaxmpm.init_state(three, params)
    p = jnp.asarray(np.random.default_rng(3).uniform(-1e5, 2e6, s.x.shape[0]))
    s = dataclasses.replace(s, stress=-p[:, None, None] * jnp.eye(2))

    @jax.jit
    def ambients(params, s):
        st = stencil(three, s.x)
        beta = ddmp_beta(st.xi)
        g = particle_to_grid(lay3, params, st, s, beta)
        p_amb_n = grid_acceleration(lay3, params, s, st, beta, g, None, jnp.asarray(1e-6), _mass_floor(lay3, s))[3]
        return (
            transfer.interpolate(st, lay3.field, p_amb_n[..., None])[:, 0],
            {name: ambient_pressure_by_phase(Layout.of(sc), params, st, s) for name, sc in others.items()},
        )

    by_field, by_phase = ambients(params, s)
    by_field = np.asarray(by_field)
    scale = float(jnp.max(jnp.abs(p)))
    for name, amb in by_phase.items():
        np.testing.assert_allclose(np.asarray(amb), by_field, rtol=0, atol=1e-12 * scale, err_msg=name)
    rock_sl = jaxmpm.model.state.phase_slices(three)[0]
    x, y = np.asarray(s.x[rock_sl]).T
    amb = by_field[rock_sl]
    alone = (x > 0.6) & (y < 0.4)  # nodes x >= 0.6, y <= 0.4: no gas, no water there
    assert alone.sum() >= 4 and np.all(amb[alone] == 0.0)
    assert np.all(np.abs(amb[y > 0.55]) > 1e3)  # inside the gas
    assert np.all(np.abs(amb[(x < 0.4) & (y < 0.4)]) > 1e3)  # inside the water


# ---------------------------------------------------------------------- E15: the linear fit
def fitted_and_averaged(grid, x, field, p, V, n_fields):
    """Nodal phase pressures (K, n_nodes) of the E15 fit, by the package's pipeline (linear-hat
    stencil, moments, one scatter per field, fit), and the plain V_p S_np averages by hand."""

    @jax.jit
    def fit_of(x, field, p, V):
        st = shapes.linear_stencil(grid, x)
        mom = fields.lsq_moments(st, p, V)
        nodal = transfer.scatter(st, field, mom, n_fields, grid.n_nodes)
        return fields.lsq_nodal_pressure(nodal, grid.dim, grid.h), st.node, st.w

    fit, node, wt = (np.asarray(a) for a in fit_of(jnp.asarray(x), jnp.asarray(field), jnp.asarray(p), jnp.asarray(V)))
    w = np.zeros((n_fields, grid.n_nodes))
    wp = np.zeros((n_fields, grid.n_nodes))
    for q in range(len(p)):
        np.add.at(w[field[q]], node[q], V[q] * wt[q])
        np.add.at(wp[field[q]], node[q], V[q] * wt[q] * p[q])
    return fit, w, wp


def node_positions(grid):
    axes = [grid.origin[k] + grid.h * np.arange(grid.nodes[k]) for k in range(grid.dim)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, grid.dim)


@pytest.mark.parametrize("dim", [1, 2])
def test_e15_fit_is_exact_for_linear_pressure_at_interior_edge_and_interface_nodes(dim):
    """(E15, PHYSICS 2.1 stage 3) the nodal phase pressure P_nk, the value at node n of the
    V_p S_np-weighted linear least-squares fit to field k's particle pressures, is exact for a
    linear field p = a_k + b_k . x: P_nk = a_k + b_k . x_n at every node field k touches, with
    particles at random positions. Two fields meet at x = 0.5 with different linear fields, so the
    interface nodes and the outer edge nodes see each field from one side only, where the plain
    average sum V_p p_p S_np / V_nk is biased (the test checks that it is, by more than 0.1 |b| h,
    so the fit is what makes them exact)."""
    rng = np.random.default_rng(10 + dim)
    cells = (4,) * dim
    grid = Grid(cells=cells, h=0.25)
    n = 40 * 2**dim
    x = rng.uniform(0.0, 1.0, (n, dim))
    field = (x[:, 0] > 0.5).astype(np.int32)
    V = rng.uniform(0.5, 1.5, n) * grid.h**dim / 8
    a = np.array([1.0e5, -3.0e6])
    b = np.array([[2.0e6, -5.0e5][:dim], [-7.0e6, 4.0e6][:dim]])
    p = a[field] + np.sum(b[field] * x, -1)
    fit, w, wp = fitted_and_averaged(grid, x, field, p, V, 2)
    xn = node_positions(grid)
    touched = w > 0
    exact = a[:, None] + np.einsum("kd,nd->kn", b, xn)
    scale = np.max(np.abs(p))
    np.testing.assert_allclose(fit[touched], exact[touched], rtol=0, atol=1e-10 * scale)
    np.testing.assert_array_equal(fit[~touched], 0.0)
    interface = np.isclose(xn[:, 0], 0.5)
    assert touched[0, interface].all() and touched[1, interface].all()
    average = wp / np.where(touched, w, 1.0)
    bias = np.abs(average - exact)[:, interface]
    assert np.all(bias > 0.1 * np.abs(b[:, :1]) * grid.h), bias  # one-sided: the average is off


def test_e15_fit_falls_back_to_the_plain_average_where_it_is_singular():
    """(E15) 'fall back to the average where the fit is singular': in 2D, particles of one field
    on a single line y = const make the fit's normal matrix singular at every node they touch;
    there P_n = sum V_p p_p S_np / sum V_p S_np, by hand. With a particle moved off the line in each
    cell the fit is regular again and exact for the linear field (so the line is what switches it)."""
    rng = np.random.default_rng(3)
    grid = Grid(cells=(4, 4), h=0.25)
    n = 12
    x = np.stack([rng.uniform(0.3, 0.7, n), np.full(n, 0.4)], -1)
    V = rng.uniform(0.5, 1.5, n) * 1e-3
    p = 1.0e5 + 2.0e6 * x[:, 0] - 5.0e5 * x[:, 1]
    field = np.zeros(n, np.int32)
    fit, w, wp = fitted_and_averaged(grid, x, field, p, V, 1)
    touched = w[0] > 0
    np.testing.assert_allclose(fit[0, touched], wp[0, touched] / w[0, touched], rtol=1e-12)
    exact = 1.0e5 + node_positions(grid) @ np.array([2.0e6, -5.0e5])
    assert np.max(np.abs(fit[0, touched] - exact[touched])) > 1e3  # the average is not the fit
    x[np.argmin(x[:, 0]), 1] = 0.45  # off the line, in each of
    x[np.argmax(x[:, 0]), 1] = 0.30  # the two cells
    p = 1.0e5 + 2.0e6 * x[:, 0] - 5.0e5 * x[:, 1]
    fit, w, _ = fitted_and_averaged(grid, x, field, p, V, 1)
    touched = w[0] > 0
    np.testing.assert_allclose(fit[0, touched], exact[touched], rtol=1e-10)


# -------------------------------------------------------------- water: stiffened gas and Tait
def test_stiffened_gas_water_eos_and_sound_speed_match_the_closed_forms():
    """PHYSICS section 3 (EOS; no E label): the library's water, stiffened gas
    p = (gamma - 1) rho e - gamma p_inf. By hand: e0 = (p0 + gamma p_inf) / ((gamma - 1) rho0) so that
    p(rho0, e0) = p0; at a compressed state (rho = 1.05 rho0, e = 1.2 e0) p from the formula;
    the isentropic sound speed c^2 = gamma (p + p_inf) / rho, at rest sqrt(gamma (p0 + p_inf) / rho0)
    (1625 m/s); the bulk modulus K = rho c^2 = gamma (p + p_inf), whose inverse is the kappa of (E6)."""
    water = library_material("water")
    assert water.model == "stiffened_gas"
    m = model_of(water.model)
    c = constants(water)
    g, p_inf, rho0, p0 = 4.4, 6.0e8, 1000.0, 101325.0  # Saurel & Abgrall 1999
    assert {k: float(v) for k, v in c.items()} == {"gamma": g, "p_inf": p_inf, "rho0": rho0, "p0": p0}
    p_init, e0 = m.initial(c)
    assert float(p_init) == p0
    assert float(e0) == pytest.approx((p0 + g * p_inf) / ((g - 1) * rho0), rel=1e-14)
    rho = jnp.array([rho0, 1.05 * rho0, 0.97 * rho0])
    e = jnp.array([float(e0), 1.2 * float(e0), 0.99 * float(e0)])
    A, B = eos_coefficients("stiffened_gas", c, rho)
    p = np.asarray(A + B * e)
    p_hand = (g - 1) * np.asarray(rho) * np.asarray(e) - g * p_inf
    np.testing.assert_allclose(p, p_hand, rtol=1e-13)
    assert p[0] == pytest.approx(p0, rel=1e-9)  # EOS consistency at rest
    c_hand = np.sqrt(g * (p_hand + p_inf) / np.asarray(rho))
    np.testing.assert_allclose(np.asarray(m.wave_speed(c, rho, e, 1)), c_hand, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(m.bulk_modulus(c, rho, e, 1)), g * (p_hand + p_inf), rtol=1e-13)
    assert c_hand[0] == pytest.approx(np.sqrt(g * (p0 + p_inf) / rho0), rel=1e-15)


def test_stiffened_gas_water_compressed_at_one_point_follows_its_isentrope():
    """PHYSICS section 3 (EOS) with the energy equation of 2.1 stage 5 (de = (V/m) sigma : D dt):
    a uniform compression of one particle of the library's water to rho = 1.05 rho0 (single-point
    driver) follows the stiffened-gas isentrope (p + p_inf) = (p0 + p_inf) (rho / rho0)^gamma, and at
    every step its pressure is the EOS of its own (rho, e), (gamma - 1) rho e - gamma p_inf.
    Tolerance: the update integrates de = -p dv by the trapezoidal rule; over 100 steps of this path
    its error bound (dv^3 / (12 n^2)) max|p''(v)| moves p by < 1e-7 of p + p_inf (100 Pa); 1e-6 allowed."""
    water = library_material("water")
    g, p_inf, rho0, p0 = 4.4, 6.0e8, 1000.0, 101325.0
    n, t_end = 100, 1.0
    rate = np.log(1.05) / 3 / t_end  # J = exp(-3 rate t) -> 1 / 1.05
    t, hist = drive(water, lambda t: -rate * jnp.eye(3), t_end, n)
    rho = rho0 * np.exp(3 * rate * t)
    assert rho[-1] == pytest.approx(1.05 * rho0, rel=1e-12)
    p = np.array([h.pressure for h in hist])
    e = np.array([h.energy for h in hist])
    np.testing.assert_allclose(p, (g - 1) * rho * e - g * p_inf, rtol=1e-12)
    np.testing.assert_allclose(p + p_inf, (p0 + p_inf) * (rho / rho0) ** g, rtol=1e-6)
    assert p[-1] > 1e8  # it was compressed: 0.24 GPa


def pulse_speed_between_walls(material, c_expect, cells, L=1.0):
    """`pulse_speed` of test_material_models in a 1D column between slip walls, which hold the
    pressure at rest p0 (free ends would release it in rarefactions whose velocities,
    p0 / (rho c) = 0.06 m/s for water, swamp the 1e-3 m/s pulse)."""
    return pulse_speed(material, c_expect, cells, L, walls=True)


def test_stiffened_gas_water_pulse_travels_at_its_sound_speed():
    """PHYSICS section 3 (EOS) in a 1D MPM run: a 1e-3 m/s pulse in the library's water at rest
    (p0 = 1 atm) travels at c = sqrt(gamma (p0 + p_inf) / rho0) = 1625 m/s. The measured speed
    carries the scheme's dispersion error, which falls as h^2 (second order: PHYSICS 2.2 reports
    order 2.1-2.3): halving h must cut the error by more than 2.5x, and the Richardson
    extrapolation (4 c_h/2 - c_h) / 3, which removes the h^2 term, must give c within 0.3%
    (what is left: higher orders and the centroid estimate of a pulse 6-12 cells wide)."""
    water = library_material("water")
    c = np.sqrt(4.4 * (101325.0 + 6.0e8) / 1000.0)
    coarse, fine = (pulse_speed_between_walls(water, c, cells) for cells in (200, 400))
    err_coarse, err_fine = abs(coarse / c - 1), abs(fine / c - 1)
    assert err_fine < 0.01, (coarse, fine, c)
    assert err_coarse > 2.5 * err_fine, (coarse, fine, c)
    assert (4 * fine - coarse) / 3 == pytest.approx(c, rel=3e-3), (coarse, fine, c)


def test_tait_water_pressure_and_sound_speed_match_the_closed_forms():
    """PHYSICS section 3 (EOS; 'Tait for water', no E label, formula of materials/eos.py's docstring): the
    library's water with model 'tait', p = B ((rho / rho0)^n - 1) + p0 (Cole 1948: n = 7.15,
    B = 304.6 MPa), independent of e; by hand at rest (p0), compressed 3% and expanded 1%; sound
    speed c^2 = dp/drho = n B rho^(n-1) / rho0^n, at rest c0^2 = n B / rho0 (1476 m/s); bulk modulus
    rho c^2. And one particle compressed to 1.03 rho0 by the single-point driver has that pressure."""
    water = library_material("water", "tait")
    m = model_of(water.model)
    c = constants(water)
    n, B, rho0, p0 = 7.15, 304.6e6, 1000.0, 101325.0
    assert {k: float(v) for k, v in c.items()} == {"tait_n": n, "tait_B": B, "rho0": rho0, "p0": p0}
    assert m.initial(c) == (p0, 0.0)
    rho = np.array([rho0, 1.03 * rho0, 0.99 * rho0])
    e = np.array([0.0, 5.0e4, -1.0e3])  # e has no say
    A, Be = eos_coefficients("tait", c, jnp.asarray(rho))
    p = np.asarray(A + Be * jnp.asarray(e))
    p_hand = B * ((rho / rho0) ** n - 1) + p0
    np.testing.assert_allclose(p, p_hand, rtol=1e-13)
    assert p[0] == p0
    c2_hand = n * B * rho ** (n - 1) / rho0**n
    np.testing.assert_allclose(
        np.asarray(m.wave_speed(c, jnp.asarray(rho), jnp.asarray(e), 1)) ** 2, c2_hand, rtol=1e-13
    )
    assert c2_hand[0] == pytest.approx(n * B / rho0, rel=1e-15)
    np.testing.assert_allclose(
        np.asarray(m.bulk_modulus(c, jnp.asarray(rho), jnp.asarray(e), 1)), rho * c2_hand, rtol=1e-13
    )
    steps, t_end = 20, 1.0
    rate = np.log(1.03) / 3 / t_end
    _, hist = drive(water, lambda t: -rate * jnp.eye(3), t_end, steps)
    assert hist[-1].pressure == pytest.approx(B * (1.03**n - 1) + p0, rel=1e-12)


# ------------------------------------------------------------------ concrete: Drucker-Prager
def yield_stress(c, p):
    """Y(p) = min(max(Y0 + dY_dp p, 0), Ymax): materials/strength.py's drucker_prager, by hand."""
    return min(max(c["Y0"] + c["dY_dp"] * p, 0.0), c["Ymax"])


@pytest.mark.parametrize("pressure, branch", [(50e6, "slope"), (200e6, "cap"), (-5e6, "tension cut-off")])
def test_drucker_prager_concrete_caps_von_mises_stress_at_yield_of_pressure(pressure, branch):
    """The library's concrete (linear EOS + drucker_prager + spall; PHYSICS section 3 names no
    pressure-dependent strength, so the reference is materials/strength.py's docstring Y = clip(Y0 + dY_dp p, 0,
    Ymax), by hand). One point, single-point driver: an isotropic compression (or expansion) to
    J = 1 - p / K, which sets the pressure p = -K (J - 1) and leaves the deviator zero, then an
    isochoric triaxial path L = r diag(-2, 1, 1), which keeps p fixed. The von Mises stress must be
    the elastic 6 G r t exactly until it reaches Y(p), and Y(p) after, to round-off (perfect plasticity:
    the radial return lands on the surface). At 50 MPa Y is on the slope (134 MPa), at 200 MPa on
    the cap Ymax (336 MPa); at -5 MPa Y0 + dY_dp p < 0: the tension cut-off, no shear strength at
    all. The path keeps every principal stress below the spall strength (no damage)."""
    concrete = library_material("concrete")
    assert concrete.model == "linear+drucker_prager+spall"
    c = concrete.as_dict()
    K, G = c["K"], c["G"]
    Y = yield_stress(c, pressure)
    expected_branch = (
        "tension cut-off"
        if c["Y0"] + c["dY_dp"] * pressure <= 0
        else "cap"
        if c["Y0"] + c["dY_dp"] * pressure >= c["Ymax"]
        else "slope"
    )
    assert expected_branch == branch
    n1, n2, dt = 10, 60, 1e-3
    J = 1 - pressure / K
    r_v = -np.log(J) / (3 * n1 * dt)  # tr L = -3 r_v over n1 steps
    eps_total = 1.2 * max(c["Ymax"], 1e6) / (6 * G)  # enough shear to pass any Y
    r_s = eps_total / (n2 * dt)
    L_vol = -r_v * jnp.eye(3)
    L_dev = r_s * jnp.diag(jnp.array([-2.0, 1.0, 1.0]))
    t, hist = drive(concrete, lambda t: jnp.where(t < (n1 - 0.5) * dt, L_vol, L_dev), (n1 + n2) * dt, n1 + n2)
    p = np.array([h.pressure for h in hist])
    np.testing.assert_allclose(p[n1 - 1 :], -K * (J - 1), rtol=1e-9)  # the pressure, then held
    seq = np.array([np.sqrt(1.5 * np.sum((h.stress + h.pressure * np.eye(3)) ** 2)) for h in hist])
    shear_strain = r_s * dt * np.arange(1, n2 + 1)
    expected = np.minimum(6 * G * shear_strain, Y)
    np.testing.assert_allclose(seq[n1:], expected, rtol=1e-9, atol=1e-9 * c["Y0"])
    assert np.all(np.array([h.damage for h in hist]) == 0.0)
    if Y > 0:
        assert np.sum(expected == Y) > 5  # the cap was reached
