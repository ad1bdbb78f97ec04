"""The hydrocode models' failure criteria (PHYSICS section 3): damage, which leaves failed material
without tension or shear.

Failure (damage in [0, 1], failed at 1; failed: s = 0 and p >= 0):
  spall                  damage = 1 once the largest principal stress exceeds sigma_spall
  johnson_cook_failure   damage += deps_p / eps_f, eps_f = (D1 + D2 exp(D3 sigma*))(1 + D4 ln epsdot*)
                         (1 + D5 T*), sigma* = -p / sigma_eq clipped to [-10, 10] (JC85 convention,
                         positive in tension); constants D1..D5, epsdot0, T_room, T_melt, cp
  plastic_strain         damage = eps_p / eps_f                                  eps_f
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxmpm.materials.invariants import equivalent_stress, max_principal_stress
from jaxmpm.materials.kind import ANY, POS, Constants, Part
from jaxmpm.materials.strength import THERMAL, homologous_temperature

FAILURE = {
    "spall": Part({"sigma_spall": POS + ("Pa",)}),
    "johnson_cook_failure": Part(
        {
            "D1": ANY + ("",),
            "D2": ANY + ("",),
            "D3": ANY + ("",),
            "D4": ANY + ("",),
            "D5": ANY + ("",),
            "epsdot0": POS + ("1/s",),
            **THERMAL,
        }
    ),
    "plastic_strain": Part({"eps_f": POS + ("",)}),
}


def failure_increment(
    kind: str,
    c: Constants,
    damage: jax.Array,
    eps_new: jax.Array,
    dl: jax.Array,
    epsdot: jax.Array,
    e: jax.Array,
    s: jax.Array,
    P: jax.Array,
) -> jax.Array:
    """New damage (N,) after this step's plastic strain increment dl and trial stress s - P I."""
    if kind == "spall":
        return jnp.where(max_principal_stress(s, P) > c["sigma_spall"], 1.0, damage)
    if kind == "plastic_strain":
        return jnp.maximum(damage, eps_new / c["eps_f"])
    seq = equivalent_stress(s)
    triax = jnp.clip(-P / seq, -10.0, 10.0)
    eps_f = (
        (c["D1"] + c["D2"] * jnp.exp(c["D3"] * triax))
        * (1 + c["D4"] * jnp.log(jnp.maximum(epsdot / c["epsdot0"], 1.0)))
        * (1 + c["D5"] * homologous_temperature(c, e))
    )
    return damage + dl / jnp.maximum(eps_f, 1e-6)
