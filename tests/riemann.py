"""Exact solution of the Riemann problem for an ideal gas (Toro, Riemann Solvers and Numerical
Methods for Fluid Dynamics, ch. 4): the star pressure by Newton's method on the pressure
function, then the wave pattern sampled at x / t."""

import math

import numpy as np


def _f(p, rho, pk, gamma):
    """Toro's f_K(p) and its derivative for one side (shock if p > pk, else rarefaction)."""
    a = math.sqrt(gamma * pk / rho)
    if p > pk:
        A, B = 2 / ((gamma + 1) * rho), (gamma - 1) / (gamma + 1) * pk
        f = (p - pk) * math.sqrt(A / (p + B))
        df = math.sqrt(A / (p + B)) * (1 - (p - pk) / (2 * (p + B)))
    else:
        f = 2 * a / (gamma - 1) * ((p / pk) ** ((gamma - 1) / (2 * gamma)) - 1)
        df = (p / pk) ** (-(gamma + 1) / (2 * gamma)) / (rho * a)
    return f, df


def star_state(left, right, gamma):
    """(p*, u*) of the Riemann problem; left/right = (rho, u, p)."""
    (rl, ul, pl), (rr, ur, pr) = left, right
    p = 0.5 * (pl + pr)
    for _ in range(100):
        fl, dfl = _f(p, rl, pl, gamma)
        fr, dfr = _f(p, rr, pr, gamma)
        dp = (fl + fr + ur - ul) / (dfl + dfr)
        p = max(p - dp, 1e-12)
        if abs(dp) < 1e-14 * p:
            break
    fl, _ = _f(p, rl, pl, gamma)
    fr, _ = _f(p, rr, pr, gamma)
    return p, 0.5 * (ul + ur) + 0.5 * (fr - fl)


def sample(x, t, x0, left, right, gamma):
    """(rho, u, p) arrays at positions x and time t > 0 for a diaphragm at x0."""
    (rl, ul, pl), (rr, ur, pr) = left, right
    ps, us = star_state(left, right, gamma)
    g1, g2 = (gamma - 1) / (gamma + 1), (gamma - 1) / (2 * gamma)
    out = np.empty((3, len(x)))
    for i, s in enumerate((np.asarray(x) - x0) / t):
        if s <= us:  # left of the contact
            a = math.sqrt(gamma * pl / rl)
            if ps > pl:  # left shock
                S = ul - a * math.sqrt((gamma + 1) / (2 * gamma) * ps / pl + g2)
                out[:, i] = (rl * (ps / pl + g1) / (g1 * ps / pl + 1), us, ps) if s > S else (rl, ul, pl)
            else:  # left rarefaction
                a_s = a * (ps / pl) ** g2
                if s <= ul - a:
                    out[:, i] = (rl, ul, pl)
                elif s >= us - a_s:
                    out[:, i] = (rl * (ps / pl) ** (1 / gamma), us, ps)
                else:
                    c = 2 / (gamma + 1) + g1 / a * (ul - s)
                    out[:, i] = (
                        rl * c ** (2 / (gamma - 1)),
                        2 / (gamma + 1) * (a + (gamma - 1) / 2 * ul + s),
                        pl * c ** (2 * gamma / (gamma - 1)),
                    )
        else:  # right of the contact
            a = math.sqrt(gamma * pr / rr)
            if ps > pr:  # right shock
                S = ur + a * math.sqrt((gamma + 1) / (2 * gamma) * ps / pr + g2)
                out[:, i] = (rr * (ps / pr + g1) / (g1 * ps / pr + 1), us, ps) if s < S else (rr, ur, pr)
            else:  # right rarefaction
                a_s = a * (ps / pr) ** g2
                if s >= ur + a:
                    out[:, i] = (rr, ur, pr)
                elif s <= us + a_s:
                    out[:, i] = (rr * (ps / pr) ** (1 / gamma), us, ps)
                else:
                    c = 2 / (gamma + 1) - g1 / a * (ur - s)
                    out[:, i] = (
                        rr * c ** (2 / (gamma - 1)),
                        2 / (gamma + 1) * (-a + (gamma - 1) / 2 * ur + s),
                        pr * c ** (2 * gamma / (gamma - 1)),
                    )
    return out
