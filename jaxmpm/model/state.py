"""State: what evolves (a pytree of arrays), and the initial sampling of geometry into particles.

Particles of all phases are stored in one set of arrays, phase after phase in scene order; the
slice of each phase is static (`phase_slices`), fixed by the scene.

    t       ()        time, s
    x       (N, d)    position, m
    v       (N, d)    velocity, m/s
    mass    (N,)      kg (constant)
    volume  (N,)      current material volume, m^3
    (mass and volume in 3D; per unit depth in 2D, kg/m and m^2, per unit area in 1D, kg/m^2 and
    m, and per radian in axisymmetric scenes, kg/rad and m^3/rad: `jaxmpm.io.units`)
    F       (N, D, D) deformation gradient (D = d, or 3 in axisymmetric scenes: r, z, theta)
    stress  (N, D, D) Cauchy stress, Pa (tension positive)
    energy  (N,)      specific internal energy, J/kg
    C       (N, d, d) APIC affine velocity matrix, 1/s (only with transfer = 'apic'; else None)
    eps_ps  (N,)      accumulated equivalent plastic strain (drives the alpha closure, E5)
    pressure (N,)     pressure the stress holds, Pa (EOS + artificial viscosity; -tr(stress)/d for
                      the total-stress models)
    damage  (N,)      damage in [0, 1]; 1: failed, no tension and no shear
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxmpm.materials.models import model_of
from jaxmpm.model.params import Params, check_params
from jaxmpm.model.sampling import first_outside, sample_phase, usable_region
from jaxmpm.model.scene import Scene


@dataclass(frozen=True)
class State:
    """What evolves (a pytree; the fields, shapes and units are in the module docstring)."""

    t: jax.Array
    x: jax.Array
    v: jax.Array
    mass: jax.Array
    volume: jax.Array
    F: jax.Array
    stress: jax.Array
    energy: jax.Array
    C: jax.Array | None = None
    eps_ps: jax.Array | None = None
    pressure: jax.Array | None = None
    damage: jax.Array | None = None

    @property
    def n_particles(self) -> int:
        return self.x.shape[-2]


jax.tree_util.register_dataclass(
    State,
    data_fields=["t", "x", "v", "mass", "volume", "F", "stress", "energy", "C", "eps_ps", "pressure", "damage"],
    meta_fields=[],
)


def phase_slices(scene: Scene) -> tuple[slice, ...]:
    """Static slice of each phase's particles in the State arrays (scene order)."""
    out, start = [], 0
    for p in scene.phases:
        n = len(sample_phase(scene.grid, p))
        out.append(slice(start, start + n))
        start += n
    return tuple(out)


def particle_fields(scene: Scene) -> np.ndarray:
    """(N,) velocity-field index of every particle (static)."""
    return np.concatenate([np.full(len(sample_phase(scene.grid, p)), p.field, np.int32) for p in scene.phases])


def init_state(scene: Scene, params: Params) -> State:
    """Initial State: particles sampled from each phase's geometry, at the rest pressure and internal
    energy of its model (zero but for gases and p0 of an EOS), with the phase's initial velocity;
    mass = rho0 * volume (rho0 from params). dtype follows params. For a built-in scene,
    `jaxmpm.initial_state` adds the initial fields its builder defines and a scene file cannot
    express (the vibrating bar's mode shape); `jaxmpm run` and `ensemble` start from that."""
    check_params(scene, params)
    d, h = scene.dim, scene.grid.h
    dtype = jnp.result_type(params.cfl)
    xs, vs, ms, vols, ps, es = [], [], [], [], [], []
    for p in scene.phases:
        x = sample_phase(scene.grid, p)
        n = len(x)
        vol = np.full(n, p.fraction * (h / p.ppc) ** d)
        if scene.axisymmetric:
            vol = vol * x[:, 0]  # per radian: V = r dr dz
        xs.append(jnp.asarray(x, dtype))
        vs.append(jnp.broadcast_to(jnp.asarray(p.velocity, dtype), (n, d)))
        vols.append(jnp.asarray(vol, dtype))
        ms.append(jnp.asarray(vol, dtype) * params.phases[p.name]["rho0"])
        p0, e0 = model_of(scene.material(p).model).initial(params.phases[p.name])
        ps.append(jnp.zeros(n, dtype) + p0)
        es.append(jnp.zeros(n, dtype) + e0)
    x, v, vol, m, pres, energy = (jnp.concatenate(a) for a in (xs, vs, vols, ms, ps, es))
    n = x.shape[0]
    md = scene.material_dim
    eye = jnp.broadcast_to(jnp.eye(md, dtype=dtype), (n, md, md))
    C = jnp.zeros((n, d, d), dtype) if scene.transfer == "apic" else None
    return State(
        t=jnp.zeros((), dtype),
        x=x,
        v=v,
        mass=m,
        volume=vol,
        F=eye,
        stress=-pres[:, None, None] * eye,
        energy=energy,
        C=C,
        eps_ps=jnp.zeros(n, dtype),
        pressure=pres,
        damage=jnp.zeros(n, dtype),
    )


def check_state_dtypes(state: State) -> None:
    """ValueError naming the first field of `state` whose dtype is not float32 or float64, or not
    the one of state.t (a step keeps each field's dtype: one dtype for all)."""
    allowed = (np.dtype(np.float32), np.dtype(np.float64))

    def dtype_of(a):
        return np.dtype(a.dtype if hasattr(a, "dtype") else np.result_type(a))

    t_dtype = dtype_of(state.t)
    for name in State.__dataclass_fields__:
        a = getattr(state, name)
        if a is None:
            continue
        dt = dtype_of(a)
        if dt not in allowed:
            raise ValueError(
                f"state.{name} has dtype {dt}: allowed float32 or float64 (all fields one dtype; "
                "jaxmpm.init_state gives the dtype of the params)"
            )
        if dt != t_dtype:
            raise ValueError(
                f"state.{name} has dtype {dt} and state.t {t_dtype}: allowed one dtype for all fields "
                "(float32 or float64)"
            )


def check_state(scene: Scene, state: State) -> None:
    """Raise ValueError naming the field, the particle (index and phase) and the allowed range if a
    concrete State does not fit the scene: array shapes, finite values, mass and volume > 0,
    damage in [0, 1], plastic strain >= 0, det F > 0, particles inside the grid."""
    # longer than 60 lines on purpose: one check per State field, in the fields' order, each a few lines
    if not isinstance(state, State):
        raise ValueError(f"state = {type(state).__name__} is invalid: allowed a jaxmpm.State")
    slices = phase_slices(scene)
    n, d, md = slices[-1].stop, scene.dim, scene.material_dim

    def phase_of(i):
        return next(p.name for p, sl in zip(scene.phases, slices) if sl.start <= i < sl.stop)

    shapes = {
        "x": (n, d),
        "v": (n, d),
        "mass": (n,),
        "volume": (n,),
        "F": (n, md, md),
        "stress": (n, md, md),
        "energy": (n,),
        "eps_ps": (n,),
        "pressure": (n,),
        "damage": (n,),
    }
    if np.shape(state.t) != ():
        raise ValueError(f"state.t has shape {np.shape(state.t)}: allowed a scalar (s)")
    check_state_dtypes(state)
    if scene.transfer == "apic":
        if state.C is None:
            raise ValueError(
                "state.C is None: the scene's transfer 'apic' needs the affine velocity matrix C, "
                f"allowed an array of shape {(n, d, d)} (1/s; zeros at rest, as init_state gives)"
            )
        shapes["C"] = (n, d, d)
    elif state.C is not None:
        raise ValueError(
            f"state.C is set, but the scene's transfer {scene.transfer!r} has no affine velocity matrix "
            "(only 'apic' carries C): allowed None"
        )
    for name, shape in shapes.items():
        a = getattr(state, name)
        if a is None:
            continue
        if tuple(np.shape(a)) != shape:
            raise ValueError(f"state.{name} has shape {tuple(np.shape(a))}: the scene needs {shape}")
        a = np.asarray(a)
        bad = ~np.isfinite(a.reshape(n, -1)).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(
                f"state.{name} of particle {i} (phase {phase_of(i)!r}) is not finite: allowed finite values"
            )
    for name, lo, hi, unit in (
        ("mass", 0.0, None, "kg"),
        ("volume", 0.0, None, "m^3"),
        ("damage", 0.0, 1.0, ""),
        ("eps_ps", 0.0, None, ""),
    ):
        a = getattr(state, name)
        if a is None:
            continue
        a = np.asarray(a)
        strict = name in ("mass", "volume")
        bad = (a <= lo if strict else a < lo) | (a > hi if hi is not None else False)
        if bad.any():
            i = int(np.argmax(bad))
            rng = f"{'>' if strict else '>='} {lo:g}" + (f" and <= {hi:g}" if hi is not None else "")
            raise ValueError(
                f"state.{name} = {float(a[i])!r} of particle {i} (phase {phase_of(i)!r}) is invalid: "
                f"allowed {rng}{' ' + unit if unit else ''}"
            )
    det = np.linalg.det(np.asarray(state.F, np.float64))
    if not (det > 0).all():
        i = int(np.argmax(~(det > 0)))
        raise ValueError(
            f"state.F of particle {i} (phase {phase_of(i)!r}) has det F = {float(det[i]):.6g}: allowed "
            "det F > 0 (a deformation gradient keeps volume positive)"
        )
    _, lo, hi = usable_region(scene)
    x = np.asarray(state.x)
    i = first_outside(x, lo, hi)
    if i is not None:
        raise ValueError(
            f"state.x of particle {i} (phase {phase_of(i)!r}) = {x[i].tolist()} m lies outside the grid: "
            f"allowed [{lo.tolist()}, {hi.tolist()}] m"
        )
