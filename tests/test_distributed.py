"""One simulation with its particles split across devices (jaxmpm.distributed): the same results,
gradients and batches as on one device. The two-device checks run in a subprocess with two host
CPU devices (XLA_FLAGS=--xla_force_host_platform_device_count=2); a one-device mesh runs the
same shard_map path in this process."""

import dataclasses
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

import jaxmpm
from jaxmpm import distributed
from jaxmpm.model.scene import Box, Grid, Phase, Scene

TWO_DEVICE_SCRIPT = r"""
import dataclasses, jax, jax.numpy as jnp, numpy as np
import jaxmpm
from jaxmpm import distributed
from jaxmpm.model.scene import Box, Grid, Phase, Scene
assert len(jax.devices()) == 2, jax.devices()
mesh = distributed.particle_mesh()

def same(a, b, what, rtol=1e-9, atol=1e-11):
    for name in ("x", "v", "volume", "stress", "energy", "damage", "eps_ps", "C"):
        x, y = getattr(a, name), getattr(b, name)
        if x is None:
            continue
        x, y = np.asarray(x), np.asarray(y)
        scale = float(np.max(np.abs(y))) + 1e-30
        if name == "C":                  # velocity gradients: on the scale of |v| / h (here round-off about 0)
            scale = max(scale, float(np.max(np.abs(np.asarray(b.v)))) / scene.grid.h)
        assert np.all(np.isfinite(x)), f"{what}: {name}"
        np.testing.assert_allclose(x, y, rtol=rtol, atol=atol * scale, err_msg=f"{what}: {name}")
    np.testing.assert_allclose(float(a.t), float(b.t), rtol=1e3 * rtol, err_msg=what)
    print("equal:", what)

# two velocity fields, DDMP, axisymmetric, exchange, interface forces and their transpose (E7),
# the alpha closure, Mie-Grueneisen + Johnson-Cook + failure: the final state and the gradient
# through the checkpointed fixed-length driver (CFL step each step)
scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2)
params = jaxmpm.default_params(scene)
s0 = jaxmpm.init_state(scene, params)
n = jaxmpm.plan_steps(scene, params, s0, 4e-7)
def momentum_and_heat(c_d, mesh):
    p = dataclasses.replace(params, drag_coefficient=c_d)
    # the impact's shock shortens the CFL step: the run ends at 3.8e-7 s, on one device as on two
    fin, _ = jaxmpm.simulate(scene, p, s0, t_end=4e-7, n_out=1, n_steps=n, checkpoint=True, mesh=mesh, allow_short=True)
    return jnp.sum(fin.mass * fin.v[:, 1]) + jnp.sum(fin.mass * fin.energy), fin
if GRADIENT:
    (v1, one), g1 = jax.value_and_grad(momentum_and_heat, has_aux=True)(jnp.asarray(1.0), None)
    (v2, two), g2 = jax.value_and_grad(momentum_and_heat, has_aux=True)(jnp.asarray(1.0), mesh)
    same(two, one, "debris cloud")
    assert float(g1) != 0.0
    np.testing.assert_allclose(float(g2), float(g1), rtol=1e-9)
    print("equal: gradient", float(g1), float(g2))
    raise SystemExit(0)
(v1, one), (v2, two) = momentum_and_heat(jnp.asarray(1.0), None), momentum_and_heat(jnp.asarray(1.0), mesh)
same(two, one, "debris cloud")

# one field with the B-spline APIC step (offset-loop transfers), gravity, slip walls; an odd
# particle count (filled up with one padding copy)
scene = jaxmpm.load_scene("mpm88", n_grid=32)
assert jaxmpm.model.state.phase_slices(scene)[0].stop % 2 == 1
params = jaxmpm.default_params(scene)
s0 = jaxmpm.init_state(scene, params)
n = 50
one = jaxmpm.simulate(scene, params, s0, t_end=n * 2e-4, n_out=1, n_steps=n, dt=2e-4)
two = jaxmpm.simulate(scene, params, s0, t_end=n * 2e-4, n_out=1, n_steps=n, dt=2e-4, mesh=mesh)
same(two[0], one[0], "mpm88 APIC")
if not FULL:
    raise SystemExit(0)
p32 = jaxmpm.default_params(scene, dtype=jnp.float32)           # float32, as users run by default
s32 = jaxmpm.init_state(scene, p32)
one = jaxmpm.simulate(scene, p32, s32, t_end=n * 2e-4, n_out=1, n_steps=n, dt=2e-4)
two = jaxmpm.simulate(scene, p32, s32, t_end=n * 2e-4, n_out=1, n_steps=n, dt=2e-4, mesh=mesh)
assert two[0].x.dtype == jnp.float32
same(two[0], one[0], "mpm88 APIC float32", rtol=1e-4, atol=1e-5)

# 3D, DDMP, one field: two elastic blocks meet
rock = jaxmpm.Material.make("rock", "hypoelastic", rho0=2000.0, E=2.0e9, nu=0.25)
scene = Scene(grid=Grid(cells=(8, 8, 12), h=0.1), materials=(rock,),
              phases=(Phase("a", "rock", Box((0.2, 0.2, 0.2), (0.6, 0.6, 0.5)), velocity=(0.0, 0.0, 20.0)),
                      Phase("b", "rock", Box((0.2, 0.2, 0.6), (0.6, 0.6, 0.9)))), t_end=8e-3, n_out=1)   # they meet at 5 ms
params = jaxmpm.default_params(scene)
s0 = jaxmpm.init_state(scene, params)
one = jaxmpm.simulate(scene, params, s0, progress=False)
two = jaxmpm.simulate(scene, params, s0, progress=False, mesh=mesh)
same(two[0], one[0], "3D DDMP blocks")
assert float(jnp.max(jnp.abs(one[0].stress))) > 1e6          # they have met: stresses of MPa

# a batch of Params (vmap) over the sharded step
n = jaxmpm.plan_steps(scene, params, s0, 8e-3, safety=2.0)
batch = jaxmpm.batch.sweep(params, cfl=[0.2, 0.3])
run = lambda p, mesh: jaxmpm.simulate(scene, p, s0, t_end=8e-3, n_out=1, n_steps=n, mesh=mesh)[0]
for k, (a, b) in enumerate(zip(jax.tree.leaves(jax.vmap(lambda p: run(p, mesh))(batch)),
                               jax.tree.leaves(jax.vmap(lambda p: run(p, None))(batch)))):
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-12 * float(np.max(np.abs(np.asarray(b)))))
print("equal: vmap")
"""


def run_on_two_devices(gradient, full=True):
    env = dict(
        os.environ,
        XLA_FLAGS=(os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip(),
        JAX_PLATFORMS="cpu",
        JAX_ENABLE_X64="1",
    )
    script = f"GRADIENT = {bool(gradient)}\nFULL = {bool(full)}\n" + TWO_DEVICE_SCRIPT
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return r.stdout


def test_two_devices_give_the_one_device_results():
    """Debris cloud (two fields, every multi-field stage) and the APIC step (float64, an odd particle
    count filled up with a padding copy): particles split across two host devices give the
    one-device results to round-off (rtol 1e-9). The float32, 3D and vmapped cases follow in the
    slow set."""
    out = run_on_two_devices(gradient=False, full=False)
    for what in ("debris cloud", "mpm88 APIC"):
        assert f"equal: {what}" in out, out
    assert "equal: vmap" not in out


@pytest.mark.slow
def test_two_devices_give_the_one_device_results_and_batches():
    """As above, and the APIC step in float32, a 3D DDMP scene and a vmapped batch of it (rtol
    1e-9; 1e-4 in float32)."""
    out = run_on_two_devices(gradient=False)
    for what in ("debris cloud", "mpm88 APIC", "mpm88 APIC float32", "3D DDMP blocks", "vmap"):
        assert f"equal: {what}" in out, out


@pytest.mark.slow
def test_two_devices_give_the_one_device_gradient():
    """d(axial momentum + internal energy) / d C_d through the checkpointed two-field debris cloud:
    two host devices give the one-device value and gradient to rtol 1e-9."""
    out = run_on_two_devices(gradient=True)
    assert "equal: debris cloud" in out and "equal: gradient" in out, out


TWO_PROCESS_SCRIPT = r"""
import sys
import jax
pid, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
jax.config.update("jax_cpu_collectives_implementation", "gloo")
jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=2, process_id=pid, initialization_timeout=120)
assert jax.process_count() == 2 and len(jax.devices()) == 2 and len(jax.local_devices()) == 1, jax.devices()
import numpy as np
import jaxmpm
from jaxmpm import distributed
from jaxmpm.model.scene import Box, Grid, Phase, Scene
mesh = distributed.particle_mesh()
results = {}
# the two-field debris cloud on the host driver (CFL step, two outputs): every multi-field stage
scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2)
params = jaxmpm.default_params(scene)
s0 = jaxmpm.init_state(scene, params)
final, history = jaxmpm.simulate(scene, params, s0, t_end=2e-7, n_out=2, progress=False, mesh=mesh)
assert not final.x.is_fully_addressable           # on both processes' devices
final, history = distributed.to_host((final, history))
for name in ("x", "v", "stress", "energy", "damage"):
    results["cloud_" + name] = getattr(final, name)
results["cloud_history_x"] = history.x
results["cloud_t"] = final.t
# a batch split across the two processes
rock = jaxmpm.Material.make("rock", "hypoelastic", rho0=2000.0, E=2.0e9, nu=0.25)
blocks = Scene(grid=Grid(cells=(20, 12), h=0.1), materials=(rock,),
               phases=(Phase("a", "rock", Box((0.2, 0.2), (0.8, 0.8)), velocity=(30.0, 0.0), field=0),
                       Phase("b", "rock", Box((0.9, 0.2), (1.5, 0.8)), field=1)),
               drag=10.0, t_end=1e-3, n_out=2)
bp = jaxmpm.default_params(blocks)
final, _ = jaxmpm.ensemble(blocks, jaxmpm.batch.sweep(bp, drag_coefficient=[3.0, 30.0, 300.0, 3000.0]))
assert not final.v.is_fully_replicated            # split across the processes
final = distributed.to_host(final)
results["batch_v"], results["batch_x"] = final.v, final.x
# a particle leaving the grid: the host driver names it, gathered from both processes
fast = Scene(grid=Grid(cells=(10, 10), h=0.1), materials=(rock,),
             phases=(Phase("block", "rock", Box((0.6, 0.4), (0.8, 0.6)), velocity=(40.0, 0.0)),), t_end=0.02)
fp = jaxmpm.default_params(fast)
try:
    jaxmpm.simulate(fast, fp, jaxmpm.init_state(fast, fp), progress=False, mesh=mesh)
except FloatingPointError as e:
    results["error"] = np.array(str(e))
if pid == 0:
    np.savez(out, **results)
print("process", pid, "done")
"""


def free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # 94 s: two JAX processes joined by jax.distributed
def test_two_processes_give_the_one_process_results(tmp_path):
    """Several hosts: two processes on localhost, joined by `jax.distributed.initialize` (CPU
    collectives over gloo), one device each. The particle-split two-field debris cloud and a
    batch split across the processes give this process's one-device results to round-off, and a
    particle that leaves the grid is named as on one device."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(JAX_PLATFORMS="cpu", JAX_ENABLE_X64="1")
    out, port = tmp_path / "two_processes.npz", str(free_port())
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", TWO_PROCESS_SCRIPT, str(pid), port, str(out)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for pid in (0, 1)
    ]
    try:
        logs = [p.communicate(timeout=600) for p in procs]
    finally:
        for p in procs:
            p.kill()
    for p, (_o, e) in zip(procs, logs):
        assert p.returncode == 0, e[-3000:]
    got = np.load(out)

    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75, fields=2)
    params = jaxmpm.default_params(scene)
    final, history = jaxmpm.simulate(
        scene, params, jaxmpm.init_state(scene, params), t_end=2e-7, n_out=2, progress=False
    )
    assert float(got["cloud_t"]) == pytest.approx(float(final.t), rel=1e-12)
    for name in ("x", "v", "stress", "energy", "damage"):
        ref = np.asarray(getattr(final, name))
        np.testing.assert_allclose(
            got["cloud_" + name], ref, rtol=1e-9, atol=1e-11 * (np.max(np.abs(ref)) + 1e-30), err_msg=name
        )
    np.testing.assert_allclose(got["cloud_history_x"], np.asarray(history.x), rtol=1e-12, atol=1e-15)
    assert np.max(np.abs(np.asarray(final.v[:, 1]) - np.asarray(history.v[0, :, 1]))) > 100.0  # the plate was hit

    blocks = two_blocks()
    bp = jaxmpm.default_params(blocks)
    ref, _ = jaxmpm.ensemble(blocks, jaxmpm.batch.sweep(bp, drag_coefficient=[3.0, 30.0, 300.0, 3000.0]), shard=False)
    np.testing.assert_allclose(got["batch_v"], np.asarray(ref.v), rtol=1e-9, atol=1e-11 * float(np.max(np.abs(ref.v))))
    np.testing.assert_allclose(got["batch_x"], np.asarray(ref.x), rtol=1e-12)
    assert not np.allclose(got["batch_v"][0], got["batch_v"][2])  # the members differ
    assert "particle" in str(got["error"]) and "of phase 'block' is outside the grid" in str(got["error"])


def two_blocks():
    rock = jaxmpm.Material.make("rock", "hypoelastic", rho0=2000.0, E=2.0e9, nu=0.25)
    return Scene(
        grid=Grid(cells=(20, 12), h=0.1),
        materials=(rock,),
        phases=(
            Phase("a", "rock", Box((0.2, 0.2), (0.8, 0.8)), velocity=(30.0, 0.0), field=0),
            Phase("b", "rock", Box((0.9, 0.2), (1.5, 0.8)), field=1),
        ),
        drag=10.0,
        t_end=1e-3,
        n_out=2,
    )


@pytest.mark.slow
def test_one_device_mesh_runs_the_sharded_step_and_gives_the_same_run():
    scene = two_blocks()
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    mesh = distributed.particle_mesh(jax.devices()[:1])
    a, ha = jaxmpm.simulate(scene, params, s0, progress=False)
    b, hb = jaxmpm.simulate(scene, params, s0, progress=False, mesh=mesh)
    for x, y in zip(jax.tree.leaves((a, ha)), jax.tree.leaves((b, hb))):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("shards", [2, 7])
def test_shard_order_gives_each_device_a_part_of_every_phase_and_inverts(shards):
    """Each device's block: ceil(n / shards) particles of each phase, phase after phase; the
    copies that fill a phase up are marked and dropped on the way back."""
    scene = two_blocks()
    counts = [sl.stop - sl.start for sl in jaxmpm.model.state.phase_slices(scene)]
    order, pad = distributed.shard_order(scene, shards)
    c = [-(-n // shards) for n in counts]
    assert len(order) == shards * sum(c) and pad.sum() == shards * sum(c) - sum(counts)
    assert sorted(order[~pad].tolist()) == list(range(sum(counts)))
    for j in range(shards):
        block = order[j * sum(c) : (j + 1) * sum(c)]
        assert np.all(block[: c[0]] < counts[0]) and np.all(block[c[0] :] >= counts[0])
    assert np.all(
        order[pad]
        == np.repeat([counts[0] - 1, sum(counts) - 1], [c[0] * shards - counts[0], c[1] * shards - counts[1]])
    )
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    perm = jax.tree.map(lambda a: a, distributed._per_particle(s0, lambda a: a[order], lambda a: a))
    back = distributed.from_shards(scene, perm, shards)
    assert all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(back), jax.tree.leaves(s0)))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_padding_copies_keep_a_normal_mass_and_volume(dtype):
    """The padding scale leaves the smallest particles of the debris cloud (volumes of 1e-12
    m^3 per radian near the axis) normal numbers in float32 and float64, so a copy's density is
    its twin's, not 0 / 0 after a flush to zero; and its share is below the dtype's round-off."""
    scene = jaxmpm.load_scene("debris_cloud", resolution=0.75)
    s0 = jaxmpm.init_state(scene, jaxmpm.default_params(scene))
    scale = distributed.padding_scale(dtype)
    smallest = min(float(np.min(s0.volume)), float(np.min(s0.mass)))
    assert smallest < 1e-10 and dtype(smallest * scale) >= np.finfo(dtype).tiny
    assert scale < np.finfo(dtype).eps / 1e6


def test_bad_meshes_and_unsupported_options_are_named():
    scene = two_blocks()
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    from jax.sharding import Mesh

    with pytest.raises(
        ValueError, match=r"mesh = .* is invalid: allowed a jax.sharding.Mesh with the one axis 'particles'"
    ):
        jaxmpm.simulate(scene, params, s0, progress=False, mesh=Mesh(np.array(jax.devices()[:1]), ("batch",)))
    with pytest.raises(ValueError, match=r"mesh is invalid with restart_file or debug"):
        jaxmpm.simulate(
            scene, params, s0, progress=False, debug=True, mesh=distributed.particle_mesh(jax.devices()[:1])
        )


def test_unsharded_step_has_no_collectives():
    """Without a mesh the step's program holds no collective (psum / pmax): the one-device path is
    what it was."""
    scene = two_blocks()
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    text = str(jax.make_jaxpr(jaxmpm.make_step(scene))(params, s0))
    assert "psum" not in text and "pmax" not in text
    assert dataclasses.is_dataclass(s0)
