"""energy_update = 'compatible' in several velocity fields: the hydrocode models' internal energy
takes the work the grid's forces did, with the continuity form's volume rate (E7, the transpose of
the interface forces) at the midpoint velocity (`jaxmpm.stages.grid_to_particle.musl_velocity_gradients`).
The one-field cases (a fragment hitting a wall, exact to round-off) are in tests/test_boundary.py."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

import jaxmpm


def debris_energy(energy_update: str) -> np.ndarray:
    """The two-field debris cloud (resolution 0.75, `tensile`, C_h = 0.02, with the drag's heat, float64,
    3 us, 12 outputs): total energy / initial at each output."""
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2, c_h=0.02, fragmentation="tensile", t_end=3e-6)
    scene = dataclasses.replace(scene, energy_update=energy_update, drag_heating=True)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, n_out=12, progress=False)
    energy = np.asarray(jax.vmap(lambda s: jaxmpm.diagnostics.total_energy(scene, params, s))(hist))
    return energy / energy[0]


def test_the_compatible_energy_update_keeps_the_two_field_debris_cloud_energy():
    """Measured at 3 us: 0.99983 of the start with 'compatible' (largest over the run 1.000000),
    0.99582 with 'midpoint' (largest 1.00015); at 6 us 0.99981 and 0.99532. What remains (2e-4) is the drag's heat and the fields'
    common pressure, which the compatible form does not make exact. Without E7's rate in the work the
    two-field dam break rose by 2% of m g a by T = 0.04 (not kept)."""
    compatible, midpoint = debris_energy("compatible"), debris_energy("midpoint")
    assert abs(compatible[-1] - 1) < 5e-4, compatible
    assert compatible.max() < 1 + 1e-5, compatible
    assert abs(midpoint[-1] - 1) > 4 * abs(compatible[-1] - 1), (midpoint, compatible)
