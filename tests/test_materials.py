"""Elastic models (linear elastic, hypoelastic with the Jaumann rate) and the material library."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxmpm.materials import elastic, known_keys, library_material

C = {"E": jnp.asarray(2.0e9), "nu": jnp.asarray(0.3), "rho0": jnp.asarray(1000.0)}


def test_jaumann_rate_rotates_stress_with_a_rigid_spin():
    """Pure spin L = W (no stretching): the Jaumann stress co-rotates, sigma(t) = R sigma0 R^T."""
    omega, t_end, n = 2.0, 0.5, 20000
    W = jnp.array([[0.0, -omega], [omega, 0.0]])[None]
    s0 = jnp.array([[3.0e6, 1.0e6], [1.0e6, -2.0e6]])[None]
    dt = t_end / n

    def body(carry, _):
        F, s = carry
        return elastic.hypoelastic_update(C, F, s, W, dt), None

    (F, s), _ = jax.lax.scan(body, (jnp.eye(2)[None], s0), None, length=n)
    a = omega * t_end
    R = jnp.array([[jnp.cos(a), -jnp.sin(a)], [jnp.sin(a), jnp.cos(a)]])
    np.testing.assert_allclose(np.asarray(s[0]), np.asarray(R @ s0[0] @ R.T), rtol=0, atol=2e-4 * 3e6)
    assert float(jnp.trace(s[0])) == pytest.approx(float(jnp.trace(s0[0])), rel=1e-9)  # spin keeps invariants


def test_hypoelastic_uniaxial_strain_matches_linear_elasticity_at_small_strain():
    lam, mu = elastic.lame(C, 3)
    eps, n = 1e-4, 100
    L = jnp.zeros((1, 3, 3)).at[0, 0, 0].set(eps)  # rate 1e-4 per unit time, integrated over t = 1
    F, s = jnp.eye(3)[None], jnp.zeros((1, 3, 3))
    for _ in range(n):
        F, s = elastic.hypoelastic_update(C, F, s, L, 1.0 / n)
    np.testing.assert_allclose(float(s[0, 0, 0]), float((lam + 2 * mu) * eps), rtol=1e-3)
    np.testing.assert_allclose(float(s[0, 1, 1]), float(lam * eps), rtol=1e-3)


def test_linear_elastic_stress_is_the_derivative_of_its_energy():
    F = jnp.eye(3)[None] + 1e-3 * jnp.array([[1.0, 0.3, -0.2], [0.1, -0.5, 0.4], [0.0, 0.2, 0.7]])[None]
    dW = jax.grad(lambda F: jnp.sum(elastic.linear_elastic_energy(C, F)))(F)
    np.testing.assert_allclose(np.asarray(dW), np.asarray(elastic.linear_elastic_stress(C, F)), rtol=1e-10)


def test_solid_wave_speed_1d_and_3d():
    rho = jnp.asarray(1000.0)
    assert float(elastic.solid_wave_speed(C, rho, 0.0, 1)) == pytest.approx((2.0e9 / 1000.0) ** 0.5)
    lam, mu = elastic.lame(C, 3)
    assert float(elastic.solid_wave_speed(C, rho, 0.0, 3)) == pytest.approx(float(((lam + 2 * mu) / rho) ** 0.5))


def test_library_keys_and_package_copy_equals_shared():
    for key in ("al2024", "al6061", "tungsten_wha", "steel_4340", "copper_ofhc", "air", "water", "concrete"):
        assert key in known_keys()
        m = library_material(key)
        assert m.as_dict()["rho0"] > 0
    shared = pathlib.Path(__file__).parents[2] / "shared" / "data" / "materials.toml"
    if not shared.exists():
        pytest.skip("../shared/data is not beside this checkout")
    package = pathlib.Path(__file__).parents[1] / "jaxmpm" / "data" / "materials.toml"
    assert package.read_text() == shared.read_text()


def test_checks_merge_over_the_shared_table_and_name_what_they_change():
    """data/verification.toml (the project's checks of the shared materials.toml) sets a checked
    sub-table's status and source, replaces only the numbers it names, and refuses a check of a
    sub-table or constant the table does not have."""
    from jaxmpm.materials import library

    raw, checks = library._data("materials.toml"), library._data("verification.toml")
    merged = library.library_table()
    for key, subs in checks.items():
        for sub, check in subs.items():
            t, before = merged[key][sub], raw[key][sub]
            assert t["verified"] == check.get("verified", before["verified"])
            assert t["source"] == check.get("source", before["source"])
            assert check.get("checked") and (check.get("read") or check.get("derived"))
            for name, value in before.items():
                if name not in ("verified", "source"):
                    assert t[name] == check.get("values", {}).get(name, value), (key, sub, name)
            if check.get("values"):
                assert "note" in check, f"{key}.{sub}: a replaced value needs its reason"
    assert merged["concrete"]["elastic"]["E"] != raw["concrete"]["elastic"]["E"]
    with pytest.raises(ValueError, match=r"\[al2024.nonesuch\] names no sub-table"):
        library.merge_checks(library._data("materials.toml"), {"al2024": {"nonesuch": {"verified": True}}})
    with pytest.raises(ValueError, match=r"values.E0 is not a constant"):
        library.merge_checks(library._data("materials.toml"), {"al2024": {"elastic": {"values": {"E0": 1.0}}}})
    with pytest.raises(ValueError, match=r"verifed is unknown"):
        library.merge_checks(library._data("materials.toml"), {"al2024": {"elastic": {"verifed": True}}})


def test_library_elastic_constants_are_one_isotropic_solid_where_the_table_derives_them():
    """Concrete's four elastic constants describe one isotropic solid (E = 9KG / (3K + G),
    nu = (3K - 2G) / (2 (3K + G))), so a model reading E and nu (hypoelastic) has the stiffness of
    the default model, which reads K and G. The shared table's E = 32e9, nu = 0.2 gave K = 17.8e9
    and G = 13.3e9 against its own 16e9 and 14.86e9."""
    c = library_material("concrete", "hypoelastic").as_dict()
    K, G = (library_material("concrete").as_dict()[k] for k in ("K", "G"))
    assert c["E"] / (3 * (1 - 2 * c["nu"])) == pytest.approx(K, rel=2e-3)
    assert c["E"] / (2 * (1 + c["nu"])) == pytest.approx(G, rel=2e-3)


def test_constants_not_in_si_units_warn():
    """A density past the densest element's, or a wave speed at rest past diamond's (rho0 given
    in g/cm^3: 32x too fast), warns and names the units; real and scaled constants do not."""
    import warnings

    from jaxmpm import Material

    with pytest.warns(UserWarning, match=r"materials\.al: its wave speed at rest is 1\d\d,\d{3} m/s.*rho0 in kg/m\^3"):
        Material.make("al", "linear_elastic", rho0=2.7, E=70e9, nu=0.3)
    with pytest.warns(
        UserWarning, match=r"materials\.al\.rho0 = 27000 kg/m\^3 is denser than any real material"
    ) as rec:
        Material.make("al", "linear_elastic", rho0=27000.0, E=70e9, nu=0.3)
    with pytest.warns(UserWarning, match=r"materials\.al\.rho0 = 27000 kg/m\^3") as rec_plain:
        Material("al", "linear_elastic", (("rho0", 27000.0), ("E", 70e9), ("nu", 0.3)))
    assert rec[0].filename == rec_plain[0].filename == __file__  # the line that made it
    with pytest.warns(UserWarning, match=r"materials\.w: its wave speed"):
        Material.make("w", "stiffened_gas", rho0=1.0, gamma=4.4, p_inf=6e8, p0=1e5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Material.make("al", "linear_elastic", rho0=2700.0, E=70e9, nu=0.3)
        Material.make("bar", "linear_elastic", rho0=1.0, E=100.0, nu=0.0)  # scaled units
        for key in known_keys():
            library_material(key)


def test_units_check_runs_while_a_step_is_traced():
    """Library materials are resolved while a step is traced: the units check evaluates the wave
    speed on constants there too (it raised a TracerArrayConversionError before)."""
    import jaxmpm

    scene = jaxmpm.Scene(
        grid=jaxmpm.Grid(cells=(8,), h=1 / 8),
        drag=1.0,
        phases=(
            jaxmpm.Phase("water", "water", jaxmpm.Box((0.0,), (0.5,)), field=0),
            jaxmpm.Phase("air", "air", jaxmpm.Box((0.5,), (1.0,)), field=1),
        ),
    )
    params = jaxmpm.default_params(scene)
    step = jaxmpm.make_step(scene)
    s = jax.jit(lambda s: jax.lax.fori_loop(0, 3, lambda i, s: step(params, s), s))(jaxmpm.init_state(scene, params))
    assert bool(jnp.all(jnp.isfinite(s.x))) and float(s.t) > 0
