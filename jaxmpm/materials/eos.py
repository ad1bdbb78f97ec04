"""The hydrocode models' equations of state (PHYSICS section 3): the pressure p(rho, e) of the
density and the specific internal energy, solved together with the energy equation.

Equations of state (all linear in e: p = A(rho) + B(rho) e, so the energy equation with the
midpoint pressure is solved exactly, without iteration):
  ideal_gas       p = (gamma - 1) rho e                               constants rho0, gamma, p0
  stiffened_gas   p = (gamma - 1) rho e - gamma p_inf                 rho0, gamma, p_inf, p0
  tait            p = tait_B ((rho / rho0)^tait_n - 1) + p0            rho0, tait_n, tait_B, p0
  mie_gruneisen   mu = rho / rho0 - 1 (Steinberg's form, linear Us = c0 + s up):
                  mu > 0: p = rho0 c0^2 mu [1 + (1 - gamma0/2) mu - a mu^2 / 2] / [1 - (s - 1) mu]^2
                              + (gamma0 + a mu) rho0 e
                  mu < 0: p = rho0 c0^2 mu + gamma0 rho e                rho0, c0, s, gamma0, a
                  (expansion with Gamma = gamma0 constant, our choice: Steinberg's Gamma rho =
                  const keeps the thermal pressure gamma0 rho0 e at any expansion, so hot failed
                  aluminium at 1% of rho0 held 10-57 GPa and sound speeds near 1000 km/s in the
                  debris cloud; gamma0 rho e tends to the gas limit a rho e of Tillotson's EOS for
                  hypervelocity impact, and equals Steinberg's form at mu = 0)
  linear          p = -K (J - 1), J = rho0 / rho                       rho0, K
p0 is the pressure at rest at rho0 (it sets the initial e); the others start at e = 0.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxmpm.materials.kind import ANY, INF, NONNEG, POS, Constants, Part


def _ideal_gas(c, rho):
    return jnp.zeros_like(rho), (c["gamma"] - 1) * rho


def _stiffened_gas(c, rho):
    return -c["gamma"] * c["p_inf"] * jnp.ones_like(rho), (c["gamma"] - 1) * rho


def _tait(c, rho):
    return c["tait_B"] * ((rho / c["rho0"]) ** c["tait_n"] - 1) + c["p0"], jnp.zeros_like(rho)


def _mie_gruneisen(c, rho):
    rho0, c0, s, g0, a = c["rho0"], c["c0"], c["s"], c["gamma0"], c["a"]
    mu = rho / rho0 - 1
    k = rho0 * c0**2
    mu_c = jnp.maximum(mu, 0.0)
    den = jnp.maximum(1 - (s - 1) * mu_c, 0.05)  # the Hugoniot's limiting compression
    comp = k * mu_c * (1 + (1 - g0 / 2) * mu_c - a / 2 * mu_c**2) / den**2
    A = jnp.where(mu > 0, comp, k * mu)
    return A, jnp.where(mu > 0, (g0 + a * mu) * rho0, g0 * rho)  # expansion: Gamma = gamma0 (gas-like)


def _linear(c, rho):
    return c["K"] * (1 - c["rho0"] / rho), jnp.zeros_like(rho)


_RHO0 = {"rho0": POS + ("kg/m^3",)}
_GAMMA = {"gamma": (1.0, INF, False, False, "")}
EOS = {
    "ideal_gas": Part(
        {**_RHO0, **_GAMMA, "p0": NONNEG + ("Pa",)},
        _ideal_gas,
        lambda c: (c["p0"], c["p0"] / ((c["gamma"] - 1) * c["rho0"])),
    ),
    "stiffened_gas": Part(
        {**_RHO0, **_GAMMA, "p_inf": NONNEG + ("Pa",), "p0": ANY + ("Pa",)},
        _stiffened_gas,
        lambda c: (c["p0"], (c["p0"] + c["gamma"] * c["p_inf"]) / ((c["gamma"] - 1) * c["rho0"])),
    ),
    "tait": Part(
        {**_RHO0, "tait_n": POS + ("",), "tait_B": POS + ("Pa",), "p0": ANY + ("Pa",)}, _tait, lambda c: (c["p0"], 0.0)
    ),
    "mie_gruneisen": Part(
        {**_RHO0, "c0": POS + ("m/s",), "s": POS + ("",), "gamma0": NONNEG + ("",), "a": (-10.0, 10.0, True, True, "")},
        _mie_gruneisen,
        lambda c: (0.0, 0.0),
    ),
    "linear": Part({**_RHO0, "K": POS + ("Pa",)}, _linear, lambda c: (0.0, 0.0)),
}


def eos_coefficients(eos: str, c: Constants, rho: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(A, B) of p = A + B e at density rho."""
    return EOS[eos].fn(c, rho)


def bulk_sound_speed2(eos: str, c: Constants, rho: jax.Array, e: jax.Array) -> jax.Array:
    """c_B^2 = dp/drho|_e + p / rho^2 dp/de (isentropic), floored at 1e-6 of its value at rest."""
    (A, B), (dA, dB) = jax.jvp(lambda r: eos_coefficients(eos, c, r), (rho,), (jnp.ones_like(rho),))
    p = A + B * e
    c2 = dA + dB * e + p * B / rho**2
    p0, e0 = EOS[eos].initial(c)
    rho0 = c["rho0"] * jnp.ones_like(rho)
    (A0, B0), (dA0, dB0) = jax.jvp(lambda r: eos_coefficients(eos, c, r), (rho0,), (jnp.ones_like(rho),))
    c2_ref = dA0 + dB0 * e0 + (A0 + B0 * e0) * B0 / rho0**2
    return jnp.maximum(c2, 1e-6 * c2_ref + 1e-30)
