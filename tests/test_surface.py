"""What a new user meets first: the built-in scenes' option ranges (one table for the checks and the
listing), the run's estimate and confirmation before it starts, magnitude checks before a run, the
run's PNG, and the packaging of notebooks and the physics documentation."""
from __future__ import annotations

import inspect
import re

import pytest

import jaxmpm
from jaxmpm import cli
from jaxmpm.scenefile import builder_options
from jaxmpm.scenes import BUILTINS
from jaxmpm.scenes.options import describe


def _floor(name):
    """The resolution floor `jaxmpm scenes NAME` lists for a scene (None where it has no resolution)."""
    words = dict((k, w) for k, _, w in describe(name)).get("resolution")
    return None if words is None else float(re.search(r">= ([0-9.e-]+)", words).group(1))


@pytest.mark.parametrize("name", [n for n in BUILTINS if "resolution" in builder_options(BUILTINS[n].build)])
def test_every_resolution_below_its_listed_floor_is_refused_naming_it(name):
    """No builder raises a too-small resolution to its minimum silently (elastic_impact ran 0.01 on
    the 8 x 8 grid of 0.125): below the listed floor the scene is refused, naming the floor; at it
    the scene is built."""
    floor = _floor(name)
    scene = jaxmpm.load_scene(name, resolution=floor)
    assert min(scene.grid.cells) >= 2
    with pytest.raises(ValueError, match=rf"{name}: resolution = .* is invalid: allowed a finite number >= {floor:.3g}"):
        jaxmpm.load_scene(name, resolution=0.9 * floor)


def test_elastic_impact_at_resolution_0_01_is_refused_and_its_floor_gives_8_cells():
    with pytest.raises(ValueError, match=r"elastic_impact: resolution = 0\.01 is invalid: allowed a finite number >= 0\.125"):
        jaxmpm.load_scene("elastic_impact", resolution=0.01)
    assert jaxmpm.load_scene("elastic_impact", resolution=0.125).grid.cells == (8, 8)
    assert jaxmpm.load_scene("elastic_impact", resolution=0.25).grid.cells == (16, 16)


@pytest.mark.parametrize("dim, ppc_scale", [(2, 1.0), (2, 2.0), (2, 0.5), (3, 1.0)])
def test_mpm88_has_one_n_grid_range_and_its_least_value_builds(dim, ppc_scale):
    """The one check of n_grid names the true least value: it builds, one below is refused naming it."""
    from jaxmpm.scene import MAX_PPC
    from jaxmpm.scenes.basic import mpm88_least_n_grid

    least = mpm88_least_n_grid(dim, ppc_scale)
    scene = jaxmpm.load_scene("mpm88", n_grid=least, dim=dim, ppc_scale=ppc_scale)
    assert scene.phases[0].ppc <= MAX_PPC
    if least > 8:
        with pytest.raises(ValueError, match=rf"mpm88: n_grid = {least - 1} is invalid: allowed an integer >= {least} "):
            jaxmpm.load_scene("mpm88", n_grid=least - 1, dim=dim, ppc_scale=ppc_scale)
    else:
        assert dim == 3


def test_mpm88_n_grid_8_on_the_command_line_names_27(tmp_path, capsys):
    assert cli.main(["run", "mpm88", "--opt", "n_grid=8", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "mpm88: n_grid = 8 is invalid: allowed an integer >= 27" in err
    assert "allowed an integer >= 8" not in err


@pytest.mark.parametrize("argv", [["scenes", "taylor_bar"], ["scenes", "--verbose"]])
def test_scenes_lists_every_option_with_its_default_and_range(capsys, argv):
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    names = [argv[1]] if argv[1] in BUILTINS else list(BUILTINS)
    blocks = {ln.split()[0]: [] for ln in out.splitlines() if ln and not ln.startswith(" ")}
    for ln in out.splitlines():
        if ln and not ln.startswith(" "):
            block = blocks[ln.split()[0]]
        elif ln.strip():
            block.append(ln)
    for name in names:
        for option, p in builder_options(BUILTINS[name].build).items():
            line = next((ln for ln in blocks[name] if re.match(rf"\s+--opt {option}\s+default", ln)), None)
            assert line is not None, (name, option)
            assert f"default {p.default!r}" in line and "allowed " in line
    if "taylor_bar" in names:
        assert re.search(r"--opt resolution\s+default 1\.0\s+allowed a finite number >= 0\.3 ", out)
    if "debris_cloud" in names:
        assert re.search(r"--opt resolution\s+default 1\.0\s+allowed a finite number >= 0\.724 ", out)


def test_scenes_refuses_an_unknown_name(capsys):
    assert cli.main(["scenes", "debris"]) == 2
    assert "scene 'debris' is not a built-in scene: allowed elastic_impact" in capsys.readouterr().err


def test_listed_ranges_are_the_ones_the_builders_check():
    """Every default is inside its listed range (the listing and the checks share one table)."""
    for name, b in BUILTINS.items():
        defaults = {k: p.default for k, p in builder_options(b.build).items() if p.default is not inspect.Parameter.empty}
        ranges = b.ranges(**defaults)
        assert set(ranges) == set(defaults), name
        for k, r in ranges.items():
            assert r.contains(defaults[k]), (name, k)
