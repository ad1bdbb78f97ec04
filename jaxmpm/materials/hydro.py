"""Hydrocode material models (PHYSICS section 3): stress = s - p I, the pressure p(rho, e) from an
equation of state solved together with the internal energy equation (or, given the grid's force
work, with the energy that work sets: `models` docstring, force_work), the deviator s from a strength
model (hypoelastic with the Jaumann rate, then a radial return onto the yield surface), and failure
criteria that leave failed material without tension or shear.

A composition 'eos[+strength][+failure...]' is built here (`compose`) from its parts: the equations
of state in `eos`, the strength models in `strength`, the failure criteria in `failure`, on the
stress invariants of `invariants` (each module's docstring lists its parts, their formulas and
constants). Their public names are importable from here as well.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxmpm.materials.eos import (
    EOS as EOS,
)
from jaxmpm.materials.eos import (
    bulk_sound_speed2 as bulk_sound_speed2,
)
from jaxmpm.materials.eos import (
    eos_coefficients as eos_coefficients,
)
from jaxmpm.materials.failure import FAILURE as FAILURE
from jaxmpm.materials.failure import failure_increment as failure_increment
from jaxmpm.materials.invariants import (
    deviator_norm2 as deviator_norm2,
)
from jaxmpm.materials.invariants import (
    equivalent_rate as equivalent_rate,
)
from jaxmpm.materials.invariants import (
    equivalent_stress as equivalent_stress,
)
from jaxmpm.materials.invariants import (
    largest_eigenvalue_2x2 as largest_eigenvalue_2x2,
)
from jaxmpm.materials.invariants import (
    largest_eigenvalue_3x3 as largest_eigenvalue_3x3,
)
from jaxmpm.materials.invariants import (
    max_principal_stress as max_principal_stress,
)
from jaxmpm.materials.invariants import (
    trace,
)
from jaxmpm.materials.kind import ANY as ANY
from jaxmpm.materials.kind import INF as INF
from jaxmpm.materials.kind import NONNEG as NONNEG
from jaxmpm.materials.kind import POS as POS
from jaxmpm.materials.kind import Model
from jaxmpm.materials.kind import Part as Part
from jaxmpm.materials.strength import (
    EPS_P_RAMP as EPS_P_RAMP,
)
from jaxmpm.materials.strength import (
    STRENGTH as STRENGTH,
)
from jaxmpm.materials.strength import (
    homologous_temperature as homologous_temperature,
)
from jaxmpm.materials.strength import (
    radial_return,
)
from jaxmpm.materials.strength import (
    rate_factor as rate_factor,
)
from jaxmpm.materials.strength import (
    thermal_softening as thermal_softening,
)


def compose(eos: str, strength: str | None, failure: tuple[str, ...]) -> Model:
    """The Model of 'eos[+strength][+failure...]'."""
    # longer than 60 lines on purpose: the material update is a closure over the chosen EOS, strength and failure
    # parts (one compiled branch per composition); written apart, its dozen intermediate values (trial stress,
    # energy solve, damage) would be passed around
    constants = dict(EOS[eos].constants)
    for part in ([STRENGTH[strength]] if strength else []) + [FAILURE[f] for f in failure]:
        constants.update(part.constants)

    def wave_speed(c, rho, e, dim):
        c2 = bulk_sound_speed2(eos, c, rho, e)
        if strength:
            c2 = c2 + 4.0 / 3.0 * c["G"] / rho
        return jnp.sqrt(c2)

    def bulk_modulus(c, rho, e, dim):
        return rho * bulk_sound_speed2(eos, c, rho, e)

    def update(c, mp, L, D, dt, work, q, alpha_of, force_work=None):
        d = L.shape[-1]
        eye = jnp.eye(d, dtype=L.dtype)
        # the deviatoric rate is the velocity field's (D); the closure (E4) changes only the volume
        # rate in L. In 1D and plane strain the out-of-plane rates are zero, so the in-plane
        # deviator of an isotropically changed L would carry the closure's volume rate into the shear
        W = 0.5 * (L - jnp.swapaxes(L, -1, -2))
        F = jnp.matmul(eye + dt * L, mp.F)
        s_old = mp.stress + mp.pressure[:, None, None] * eye
        epsdot = equivalent_rate(D)
        p_old = mp.pressure
        if strength:
            Ddev = D - (trace(D) / 3)[:, None, None] * eye
            s_tr = s_old + dt * (2 * c["G"] * Ddev + W @ s_old - s_old @ W)
            if strength == "elastic":
                s_new, dl = s_tr, jnp.zeros_like(mp.eps_ps)
            else:
                s_new, dl = radial_return(strength, c, s_tr, mp.eps_ps, epsdot, mp.energy, p_old, dt)
        else:
            s_new, dl = jnp.zeros_like(s_old), jnp.zeros_like(mp.eps_ps)
        eps_new = mp.eps_ps + dl
        qn = jnp.zeros_like(p_old) if q is None else q
        a_old = 1.0 if alpha_of is None else alpha_of(mp.eps_ps)
        a_new = 1.0 if alpha_of is None else alpha_of(eps_new)
        A, B = eos_coefficients(eos, c, mp.rho_new)
        h = 0.5 * work * trace(D)

        def energy_solve(s):
            if force_work is not None:  # the work of the stress the grid saw, sigma_f^n : D_f
                D_f, w_f, ambient = force_work
                w_dev = w_f * jnp.sum(s_old * D_f, axis=(-1, -2))
                e = mp.energy + w_dev - w_f * a_old * p_old * trace(D_f)
                return (e if ambient is None else e + ambient), w_dev
            w_dev = work * jnp.sum(0.5 * (s_old + s) * D, axis=(-1, -2))
            e = (mp.energy + w_dev - h * (a_old * p_old + a_new * (A + qn))) / (1 + h * a_new * B)
            return e, w_dev

        e_new, _ = energy_solve(s_new)
        p_new = A + B * e_new
        damage = mp.damage
        for f in failure:
            damage = failure_increment(f, c, damage, eps_new, dl, epsdot, mp.energy, s_new, p_new + qn)
        if failure:
            damage = jnp.clip(damage, 0.0, 1.0)
            failed = damage >= 1.0
            s_new = jnp.where(failed[:, None, None], 0.0, s_new)
            e_new, w_dev = energy_solve(s_new)
            p_new = A + B * e_new
            p_new = jnp.where(failed, jnp.maximum(p_new, 0.0), p_new)
            if force_work is None:  # the midpoint pressure's work, with the failed pressure clipped at 0
                e_new = mp.energy + w_dev - h * (a_old * p_old + a_new * (p_new + qn))
        P = p_new + qn
        return mp._replace(
            F=F, stress=s_new - P[:, None, None] * eye, pressure=P, energy=e_new, eps_ps=eps_new, damage=damage
        )

    def initial(c):
        return EOS[eos].initial(c)

    return Model(constants, update, wave_speed, bulk_modulus, initial=initial, hydro=True)
