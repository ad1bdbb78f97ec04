"""Property-based checks of scene input (hypothesis): random valid scenes run with finite results;
random malformed scene files always give a ValueError that names a field, never another exception."""

import copy
import dataclasses

import jax
import jax.numpy as jnp
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxmpm
from jaxmpm.io.scenefile import scene_from_dict, scene_from_toml

BASE = {
    "name": "prop",
    "t_end": 1e-3,
    "grid": {"cells": [8, 8], "h": 0.125},
    "materials": {"m": {"model": "linear_elastic", "rho0": 1000.0, "E": 1e6, "nu": 0.3}},
    "effects": {"gravity": [0.0, -9.81]},
    "phase": [
        {
            "name": "a",
            "material": "m",
            "velocity": [1.0, 0.0],
            "geometry": {"type": "box", "lo": [0.25, 0.25], "hi": [0.5, 0.5]},
        }
    ],
}

FIELD_WORDS = (
    "grid",
    "phase",
    "materials",
    "effects",
    "boundary",
    "output",
    "cfl",
    "t_end",
    "shape",
    "transfer",
    "name",
    "description",
    "geometry",
    "TOML",
    "key",
)

junk = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.lists(st.integers(-5, 5), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


def _paths(d, prefix=()):
    if isinstance(d, dict):
        for k, v in d.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield prefix + (i,)
            yield from _paths(v, prefix + (i,))


PATHS = list(_paths(BASE))


def _set(d, path, value):
    node = d
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value


def _delete(d, path):
    node = d
    for p in path[:-1]:
        node = node[p]
    if isinstance(node, dict):
        del node[path[-1]]
    else:
        node.pop(path[-1])


@pytest.mark.filterwarnings(
    "ignore:materials\\.m.*(faster|denser) than any real material:UserWarning"
)  # random constants
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(path=st.sampled_from(PATHS), value=junk, action=st.sampled_from(["replace", "delete", "add"]))
def test_malformed_scene_dict_gives_a_value_error_naming_a_field(path, value, action):
    d = copy.deepcopy(BASE)
    if action == "replace":
        _set(d, path, value)
    elif action == "delete":
        _delete(d, path)
    else:
        node = d
        for p in path:
            node = node[p]
        if not isinstance(node, dict):
            return
        node["unexpected_key"] = value
    try:
        scene_from_dict(d)
    except ValueError as e:
        assert any(w in str(e) for w in FIELD_WORDS), str(e)
    # a mutation that still describes a valid scene may build: that is fine too


REQUIRED = [
    ("grid",),
    ("grid", "cells"),
    ("grid", "h"),
    ("materials",),
    ("materials", "m", "rho0"),
    ("materials", "m", "E"),
    ("materials", "m", "model"),
    ("phase",),
    ("phase", 0, "material"),
    ("phase", 0, "geometry"),
    ("phase", 0, "geometry", "lo"),
]
NUMERIC = [
    ("grid", "h"),
    ("grid", "cells"),
    ("materials", "m", "rho0"),
    ("materials", "m", "E"),
    ("materials", "m", "nu"),
    ("t_end",),
    ("phase", 0, "velocity"),
    ("phase", 0, "geometry", "lo"),
    ("effects", "gravity"),
]


@pytest.mark.parametrize("path", REQUIRED, ids=lambda p: ".".join(map(str, p)))
def test_a_scene_dict_missing_a_required_entry_is_refused_naming_it(path):
    """The oracle the random mutations above lack: these deletions can never describe a scene."""
    d = copy.deepcopy(BASE)
    _delete(d, path)
    with pytest.raises(ValueError, match="material" if path == ("materials",) else str(path[-1])):
        scene_from_dict(d)


@pytest.mark.parametrize(
    "path, value",
    [
        (p, v)
        for p in NUMERIC
        for v in ("abc", None, {"a": 1}, True)
        if not (v is None and p[-1] in ("velocity", "gravity"))
    ],  # None: left out
    ids=lambda x: ".".join(map(str, x)) if isinstance(x, tuple) else repr(x),
)
def test_a_scene_dict_with_a_non_number_where_a_number_belongs_is_refused(path, value):
    d = copy.deepcopy(BASE)
    _set(d, path, value)
    with pytest.raises(ValueError, match=str(path[-1])):
        scene_from_dict(d)


def _table(path):
    node = BASE
    for p in path:
        node = node[p]
    return isinstance(node, dict)


@pytest.mark.parametrize("path", [p for p in PATHS + [()] if _table(p)], ids=lambda p: ".".join(map(str, p)) or "top")
def test_an_unknown_key_anywhere_in_a_scene_dict_is_refused_naming_it(path):
    d = copy.deepcopy(BASE)
    node = d
    for p in path:
        node = node[p]
    node["unexpected_key"] = 1.0
    with pytest.raises(ValueError, match="unexpected_key"):
        scene_from_dict(d)


@settings(max_examples=200, deadline=None)
@given(text=st.text(max_size=60))
def test_random_text_as_scene_file_gives_value_error(text):
    try:
        scene_from_toml(text, "random.toml")
    except ValueError as e:
        assert "random.toml" in str(e) or any(w in str(e) for w in FIELD_WORDS), str(e)


# at CFL 0.1 a particle moves at most 2 cells in 20 steps: every box keeps 3 cells from the edges
BOXES = (((0.25, 0.3), (0.5, 0.6)), ((0.35, 0.25), (0.65, 0.45)), ((0.2, 0.5), (0.8, 0.75)), ((0.4, 0.4), (0.6, 0.8)))


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    box=st.sampled_from(BOXES),
    vel=st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
    E=st.floats(1e5, 1e9),
    nu=st.floats(-0.5, 0.45),
    rho=st.floats(10.0, 2e4),
    shape=st.sampled_from(["ddmp", "linear"]),
    fields=st.sampled_from([1, 2]),
)
@pytest.mark.slow
def test_random_valid_scenes_run_20_steps_finite(box, vel, E, nu, rho, shape, fields):
    """Geometry, shape and grouping pick the compiled step (a few cached); material constants and
    velocities are Params and State, so each example runs without recompiling. (A body that leaves
    the grid is not a valid scene: that is the runtime guard's business.)"""
    scene = _scene(box, shape, fields)
    params = jaxmpm.default_params(scene)
    for name in ("a", "b"):
        params = params.with_constant(name, "E", E).with_constant(name, "nu", nu).with_constant(name, "rho0", rho)
    state = jaxmpm.init_state(scene, params)
    sl = jaxmpm.model.state.phase_slices(scene)[0]
    state = dataclasses.replace(state, v=state.v.at[sl].set(jnp.asarray(vel)))
    final = _run20(scene)(params, state)
    assert all(bool(jnp.all(jnp.isfinite(a))) for a in jax.tree.leaves(final))
    assert float(final.t) > 0


_CACHE = {}


def _scene(box, shape, fields):
    mat = jaxmpm.Material.make("m", "hypoelastic", rho0=1000.0, E=1e6, nu=0.3)
    phases = (
        jaxmpm.Phase("a", "m", jaxmpm.Box(*box)),
        jaxmpm.Phase("b", "m", jaxmpm.Box((0.2, 0.0), (0.8, 0.125)), field=fields - 1),
    )
    return jaxmpm.Scene(
        grid=jaxmpm.Grid(cells=(16, 16), h=1 / 16),
        materials=(mat,),
        phases=phases,
        shape=shape,
        cfl=0.1,
        drag=10.0 if fields > 1 else None,
        boundary=jaxmpm.Boundary(faces=(("y_lo", "fixed"),)),
    )


def _run20(scene):
    if scene not in _CACHE:
        step = jaxmpm.make_step(scene)
        _CACHE[scene] = jax.jit(lambda p, s: jax.lax.fori_loop(0, 20, lambda i, s: step(p, s), s))
    return _CACHE[scene]


def test_the_scene_file_format_documented_in_scenefile_loads_as_written():
    """jaxmpm/scenefile.py's docstring (README points there for the format): its example is a
    valid scene file, and every key its first paragraph lists is one the reader accepts."""
    import re

    import jaxmpm.io.scenefile as sf

    example = "\n".join(
        line[4:] for line in sf.__doc__.splitlines() if line.startswith("    ") and not line.startswith("    {")
    )
    scene = scene_from_toml(example)
    assert scene.name == "block_on_floor" and [m.key for m in scene.materials] == ["soft", "plate"]
    assert scene.materials[1].model == "hypoelastic"
    listed = set(re.findall(r"\b[a-z_]+\b", sf.__doc__.split("\n\n")[1]))
    for keys in (sf.TOP_KEYS, sf.GRID_KEYS, sf.EFFECT_KEYS, sf.OUTPUT_KEYS, sf.PHASE_KEYS):
        assert set(keys) <= listed, set(keys) - listed
