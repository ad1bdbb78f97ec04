"""The hydrocode models' strength (PHYSICS section 3): the deviator s, hypoelastic with the
Jaumann rate, returned radially onto the yield surface.

Strength (shear modulus G):
  elastic                deviatoric Jaumann rate, no yield                       G
  von_mises              elastic-perfectly plastic J2, yield stress Y            G, Y
  johnson_cook           Y = (A + B eps_p^n)(1 + C ln max(epsdot / epsdot0, 1))  G, A, B, n, C, epsdot0
  johnson_cook_thermal   ... x (1 - T*^m), T* = (T - T_room) / (T_melt - T_room) clipped to [0, 1],
                         adiabatic T = T_room + e / cp (all internal energy counted as heat)
                                                                                 + m, T_room, T_melt, cp
  drucker_prager         Y = clip(Y0 + dY_dp p, 0, Ymax) (pressure-dependent, concrete)  G, Y0, dY_dp, Ymax
  johnson_cook_plastic_rate, johnson_cook_thermal_plastic_rate
                         the same with epsdot the equivalent PLASTIC strain rate dlambda / dt, as
                         Johnson & Cook define it (same constants)
epsdot is the equivalent total strain rate sqrt(2/3 D':D') (the plastic one for the *_plastic_rate
kinds); the hardening is solved by Newton's method on sigma_eq_trial - 3 G dlambda =
Y(eps_p + dlambda, rate) (8 iterations, 15 with the plastic rate; fixed for tracing),
differentiated implicitly at the root rather than through the iterations.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from jaxmpm.materials.invariants import equivalent_stress
from jaxmpm.materials.kind import NONNEG, POS, Constants, Part

_G = {"G": POS + ("Pa",)}
_JC = {
    **_G,
    "A": POS + ("Pa",),
    "B": NONNEG + ("Pa",),
    "n": (0.0, 1.0, False, True, ""),
    "C": NONNEG + ("",),
    "epsdot0": POS + ("1/s",),
}
THERMAL = {"T_room": POS + ("K",), "T_melt": POS + ("K",), "cp": POS + ("J/(kg K)",)}
STRENGTH = {
    "elastic": Part(_G),
    "von_mises": Part({**_G, "Y": POS + ("Pa",)}),
    "johnson_cook": Part(_JC),
    "johnson_cook_thermal": Part({**_JC, "m": (0.0, 10.0, False, True, ""), **THERMAL}),
    "johnson_cook_plastic_rate": Part(_JC),
    "johnson_cook_thermal_plastic_rate": Part({**_JC, "m": (0.0, 10.0, False, True, ""), **THERMAL}),
    "drucker_prager": Part({**_G, "Y0": NONNEG + ("Pa",), "dY_dp": NONNEG + ("",), "Ymax": POS + ("Pa",)}),
}


def _safe_pow(x, n):
    """x^n for x >= 0 with finite gradients at x = 0."""
    pos = x > 0
    return jnp.where(pos, jnp.where(pos, x, 1.0) ** n, 0.0)


def homologous_temperature(c: Constants, e: jax.Array) -> jax.Array:
    """T* = (T - T_room) / (T_melt - T_room) in [0, 1], adiabatic T = T_room + e / cp."""
    return jnp.clip(e / c["cp"] / (c["T_melt"] - c["T_room"]), 0.0, 1.0)


def rate_factor(c: Constants, epsdot: jax.Array) -> jax.Array:
    return 1 + c["C"] * jnp.log(jnp.maximum(epsdot / c["epsdot0"], 1.0))


def thermal_softening(strength: str, c: Constants, e: jax.Array) -> jax.Array:
    """Johnson-Cook's thermal factor 1 - T*^m (N,) of the specific internal energy e (J/kg) for
    'johnson_cook_thermal*' strengths, else 1."""
    if strength.removesuffix("_plastic_rate") == "johnson_cook_thermal":
        return 1 - _safe_pow(homologous_temperature(c, e), c["m"])
    return jnp.ones_like(e)


EPS_P_RAMP = 1e-12  # plastic strain below which Johnson-Cook's hardening is linear in eps_p (`flow_stress`)


def flow_stress(
    strength: str, c: Constants, eps: jax.Array, epsdot: jax.Array, softening: jax.Array, p: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Yield stress Y(eps_p) (N,) Pa and its derivative dY/deps_p; softening: `thermal_softening`."""
    strength = strength.removesuffix("_plastic_rate")
    if strength == "von_mises":
        return c["Y"] * jnp.ones_like(eps), jnp.zeros_like(eps)
    if strength == "drucker_prager":
        return jnp.clip(c["Y0"] + c["dY_dp"] * p, 0.0, c["Ymax"]), jnp.zeros_like(eps)
    scale = rate_factor(c, epsdot)
    if strength == "johnson_cook_thermal":
        scale = scale * softening
    # One power per evaluation (eps^(n-1) = eps^n / eps). Below EPS_P_RAMP the hardening B eps^n
    # is a straight line from 0, so that Y(0) = A at first yield (eps^n itself has an infinite
    # slope there, which Newton's steps cannot take) and dY is that line's slope: finite and
    # consistent with Y. Above it, Y and dY are Johnson-Cook's own.
    eps_s = jnp.maximum(eps, EPS_P_RAMP)
    power = eps_s ** c["n"]
    below = eps < EPS_P_RAMP
    hardening = jnp.where(below, power * (eps / EPS_P_RAMP), power)
    Y = (c["A"] + c["B"] * hardening) * scale
    dY = c["B"] * jnp.where(below, 1.0, c["n"]) * (power / eps_s) * scale
    return Y, dY


def _implicit_root(residual, solve, dl0, *inputs):
    """The root dl in [0, dl0] of f(dl, *inputs), residual(dl, *inputs) = (f, -df/d(dl) > 0),
    found by solve(dl0, *inputs) on the inputs' values and differentiated implicitly: its tangent
    is f's tangent at the root over the slope (the implicit function theorem, from
    f(dl(x), x) = 0), one evaluation of f where differentiating the iterations would transpose
    each of them. The value is the solver's. This holds where the solver has converged: Newton on
    Johnson-Cook (Al 2024, 20,000 sampled states with overstress up to 30x) returns a stress within
    7e-11 of the trial stress of the exact root after 8 iterations at first yield, eps_p = 0, where
    the hardening's slope is infinite, and to round-off after 2 where eps_p > 0. The bracketed
    Newton of the plastic-rate kinds leaves |f| within 2e-10 of sigma_eq_trial after its 15 steps
    (steel 42CrMo4 and Al 2024, 20,000 sampled states each: 30% at eps_p = 0, dt 1e-10 to 1e-6 s,
    overstress up to 30x)."""
    sg = jax.lax.stop_gradient
    dl = solve(sg(dl0), *sg(inputs))
    f, slope = residual(dl, *inputs)
    step = f / sg(slope)  # about zero at the root; its tangent is the root's
    return dl + (step - sg(step))


def _newton(residual, iterations):
    """solve(dl0, *inputs): `iterations` Newton steps on residual from dl0, kept in [0, dl0]."""

    def solve(dl0, *inputs):
        dl = dl0
        for _ in range(iterations):
            f, slope = residual(dl, *inputs)
            dl = jnp.clip(dl + f / slope, 0.0, dl0)
        return dl

    return solve


def _bracketed_newton(residual, iterations):
    """solve(dl0, *inputs) for f(0+) > 0 > f(dl0): Newton from dl0 kept inside the bracket that
    the signs of f narrow. Where a Newton step would leave it, Newton's step in log(dl),
    dl exp(f / (slope dl)), which stays positive and crosses decades at once (the root often lies
    decades below dl0); bisection where that leaves it too. Bisection alone as the fallback left
    |f| at 1e-3 of sigma_eq_trial after 20 steps and 2e-9 after 30 on the sampled states of
    `_implicit_root`; with the log step 3e-9 after 10 and 2e-10 after 15."""

    def solve(dl0, *inputs):
        dl, lo, hi = dl0, jnp.zeros_like(dl0), dl0
        for _ in range(iterations):
            f, slope = residual(dl, *inputs)
            lo, hi = jnp.where(f > 0, dl, lo), jnp.where(f > 0, hi, dl)
            step = dl + f / slope
            log_step = dl * jnp.exp(jnp.clip(f / (slope * jnp.where(dl > 0, dl, 1.0)), -50.0, 50.0))
            dl = jnp.where(
                (step > lo) & (step < hi), step, jnp.where((log_step > lo) & (log_step < hi), log_step, 0.5 * (lo + hi))
            )
        return dl

    return solve


def radial_return(
    strength: str,
    c: Constants,
    s_tr: jax.Array,
    eps: jax.Array,
    epsdot: jax.Array,
    e: jax.Array,
    p: jax.Array,
    dt: ArrayLike | None = None,
    iterations: int = 8,
) -> tuple[jax.Array, jax.Array]:
    """Return the trial deviator onto Y(eps_p + dlambda): (s, dlambda). Newton on
    f(dl) = sigma_eq_trial - 3 G dl - Y(eps_p + dl), started at the perfectly plastic step. With a
    *_plastic_rate strength the rate in Y is dl / dt (the step's equivalent plastic strain rate; the
    yield test uses the reference rate), dY/d(dl) has the rate term's C Y_0 / dl, and the Newton
    steps (15) are kept inside the bracket [0, dl0]. Both are differentiated implicitly
    (`_implicit_root`)."""
    G = c["G"]
    seq = equivalent_stress(s_tr)
    plastic_rate = strength.endswith("_plastic_rate")
    soft = thermal_softening(strength, c, e)
    Y0, _ = flow_stress(strength, c, eps, jnp.zeros_like(epsdot) if plastic_rate else epsdot, soft, p)
    plastic = seq > Y0
    dl0 = jnp.where(plastic, (seq - Y0) / (3 * G), 0.0)
    dl = dl0
    if strength.startswith("johnson_cook") and not plastic_rate:

        def residual(dl, c, seq, eps, epsdot, e, p):
            Y, dY = flow_stress(strength, c, eps + dl, epsdot, e, p)
            return seq - 3 * c["G"] * dl - Y, 3 * c["G"] + dY

        dl = _implicit_root(residual, _newton(residual, iterations), dl0, c, seq, eps, epsdot, soft, p)
    elif plastic_rate:  # f(0+) > 0 > f(dl0)

        def residual(dl, c, seq, eps, e, p, dt):
            rate = dl / dt
            Y, dY = flow_stress(strength, c, eps + dl, rate, e, p)
            above = rate > c["epsdot0"]
            dY = dY + jnp.where(above, Y / rate_factor(c, rate) * c["C"] / jnp.where(above, dl, 1.0), 0.0)
            return seq - 3 * c["G"] * dl - Y, 3 * c["G"] + dY

        dl = _implicit_root(residual, _bracketed_newton(residual, 15), dl0, c, seq, eps, soft, p, dt)
    dl = jnp.where(plastic, dl, 0.0)
    factor = jnp.where(plastic, (seq - 3 * G * dl) / seq, 1.0)
    return s_tr * factor[:, None, None], dl
