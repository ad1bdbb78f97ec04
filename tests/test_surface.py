"""What a new user meets first: the built-in scenes' option ranges (one table for the checks and the
listing), the run's estimate and confirmation before it starts, magnitude checks before a run, the
run's PNG, and the packaging of notebooks and the physics documentation."""

from __future__ import annotations

import inspect
import re

import pytest

import jaxmpm
from jaxmpm import cli
from jaxmpm.scenes.options import builder_options
from jaxmpm.scenes import BUILTINS
from jaxmpm.scenes import describe


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
    with pytest.raises(
        ValueError, match=rf"{name}: resolution = .* is invalid: allowed a finite number >= {floor:.3g}"
    ):
        jaxmpm.load_scene(name, resolution=0.9 * floor)


def test_elastic_impact_at_resolution_0_01_is_refused_and_its_floor_gives_8_cells():
    with pytest.raises(
        ValueError, match=r"elastic_impact: resolution = 0\.01 is invalid: allowed a finite number >= 0\.125"
    ):
        jaxmpm.load_scene("elastic_impact", resolution=0.01)
    assert jaxmpm.load_scene("elastic_impact", resolution=0.125).grid.cells == (8, 8)
    assert jaxmpm.load_scene("elastic_impact", resolution=0.25).grid.cells == (16, 16)


@pytest.mark.parametrize("dim, ppc_scale", [(2, 1.0), (2, 2.0), (2, 0.5), (3, 1.0)])
def test_mpm88_has_one_n_grid_range_and_its_least_value_builds(dim, ppc_scale):
    """The one check of n_grid names the true least value: it builds, one below is refused naming it."""
    from jaxmpm.model.scene import MAX_PPC
    from jaxmpm.scenes.basic import mpm88_least_n_grid

    least = mpm88_least_n_grid(dim, ppc_scale)
    scene = jaxmpm.load_scene("mpm88", n_grid=least, dim=dim, ppc_scale=ppc_scale)
    assert scene.phases[0].ppc <= MAX_PPC
    if least > 8:
        with pytest.raises(
            ValueError, match=rf"mpm88: n_grid = {least - 1} is invalid: allowed an integer >= {least} "
        ):
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
        defaults = {
            k: p.default for k, p in builder_options(b.build).items() if p.default is not inspect.Parameter.empty
        }
        ranges = b.ranges(**defaults)
        assert set(ranges) == set(defaults), name
        for k, r in ranges.items():
            assert r.contains(defaults[k]), (name, k)


# --- the run's plan, its estimate and the confirmation (issue: no silent huge or endless run) ----


def _impact(**overrides):
    import jax

    jax.config.update("jax_enable_x64", True)
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25, overrides=overrides or None)
    params = jaxmpm.default_params(scene)
    return scene, params, jaxmpm.init_state(scene, params)


def test_run_past_its_time_threshold_stops_after_the_first_chunk_unless_confirmed(tmp_path):
    """The plan (particles, nodes, steps, memory) is announced before the run, the time estimate
    after its first chunk; over max_minutes the run stops (ValueError naming the estimate and
    yes=True) before it saves anything; yes=True runs it."""
    scene, params, state = _impact()
    lines = []
    restart = tmp_path / "r.restart.h5"
    with pytest.raises(
        ValueError,
        match=r"elastic_impact: the run is estimated to take about .* from its first chunk\), "
        r"over the 1e-09 min allowed without confirmation: run it with --yes \(Python: yes=True\)",
    ):
        jaxmpm.simulate(
            scene,
            params,
            state,
            t_end=0.2,
            n_out=2,
            progress=False,
            max_minutes=1e-9,
            announce=lines.append,
            restart_file=str(restart),
            restart_every=1,
        )
    assert not restart.exists()
    plan = lines[0]
    n = state.x.shape[0]
    assert re.match(
        rf"plan: {n:,} particles, 289 nodes x 1 velocity field\(s\), about [\d,]+ steps to t = 0\.2 s .* "
        r"memory at least [\d.]+ (KiB|MiB)",
        plan,
    )
    steps = int(re.search(r"about ([\d,]+) steps", plan).group(1).replace(",", ""))
    assert steps == jaxmpm.plan_steps(scene, params, state, 0.2, safety=1.0)
    assert re.match(r"first chunk: \d+ steps in .* s \(compilation .* s\): the run's [\d,]+ steps take about", lines[1])
    lines.clear()
    final, _ = jaxmpm.simulate(
        scene, params, state, t_end=0.2, n_out=2, progress=False, max_minutes=1e-9, yes=True, announce=lines.append
    )
    assert float(final.t) == pytest.approx(0.2) and lines[1].startswith("first chunk:")


def test_time_threshold_from_the_environment(monkeypatch):
    from jaxmpm.run.planning import max_minutes

    monkeypatch.setenv("JAXMPM_MAX_MINUTES", "2.5")
    assert max_minutes() == 2.5 and max_minutes(7) == 7.0
    monkeypatch.setenv("JAXMPM_MAX_MINUTES", "soon")
    with pytest.raises(ValueError, match=r"\$JAXMPM_MAX_MINUTES = 'soon' is invalid: allowed a number of minutes > 0"):
        max_minutes()
    monkeypatch.delenv("JAXMPM_MAX_MINUTES")
    assert max_minutes() == 60.0


def test_endless_run_on_the_command_line_is_refused_with_its_plan_and_estimate(tmp_path, capsys):
    """t_end = 1e9 s on the vibrating bar (a stable 1D scene) prints its plan (hundreds of
    billions of steps) and stops after the first chunk at the default threshold; nothing is left."""
    out = tmp_path / "o"
    code = cli.main(["run", "vibrating_bar", "--opt", "cells=20", "--t-end", "1e9", "--out", str(out), "--no-progress"])
    captured = capsys.readouterr()
    assert code == 2, captured.err
    assert re.search(
        r"plan: [\d,]+ particles, 25 nodes x 1 velocity field\(s\), about [\d,]{12,} steps to t = 1e\+09 s",
        captured.out,
    )
    assert "first chunk:" in captured.out
    assert re.search(
        r"error: vibrating_bar: the run is estimated to take about [\d.]+ (h|days) .* over the 60 min "
        r"allowed without confirmation: run it with --yes",
        captured.err,
    )
    assert not out.exists()


def test_history_beyond_the_memory_is_refused_before_the_state_is_made(tmp_path, capsys, monkeypatch):
    import jaxmpm.model.memory

    monkeypatch.setattr(jaxmpm.model.memory, "available_memory", lambda: 2**20)
    code = cli.main(
        ["run", "--opt", "resolution=0.25", "--n-out", "100000", "--out", str(tmp_path / "o"), "--no-progress"]
    )
    assert code == 2
    assert re.search(
        r"error: n_out = 100000 with \d+ particles and grid\.cells = \[16, 16\] is invalid here: the run keeps "
        r"100001 states of .* more than the 1 MiB of memory available",
        capsys.readouterr().err,
    )
    scene, params, state = _impact()
    with pytest.raises(ValueError, match=r"n_out = 100000 with .* more than the 1 MiB of memory available"):
        jaxmpm.simulate(scene, params, state, n_out=100_000, progress=False)


def test_max_minutes_must_be_positive(tmp_path, capsys):
    assert cli.main(["run", "--max-minutes", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--max-minutes 0.0 is invalid: allowed a number of minutes > 0" in capsys.readouterr().err


# --- magnitudes checked against the scene's scales before a run ---------------------------------


def test_gravity_that_moves_a_particle_more_than_a_cell_per_step_is_refused_before_running():
    """|g| dt^2 > h at the initial CFL step: refused naming gravity and the allowed bound h / dt^2;
    a gravity just inside the bound is accepted (the bound is the one computed, not a guess)."""
    scene, params, state = _impact(**{"effects.gravity": [0.0, -1e30]})
    with pytest.raises(
        ValueError,
        match=r"gravity = \[0\.0, -1e\+30\] m/s\^2 is too large for the grid and time step: "
        r"in one step of dt = .* s it moves a particle at rest .* m, more than a cell "
        r"\(h = 0\.0625 m\): allowed \|gravity\| <= h / dt\^2 = .* m/s\^2",
    ):
        jaxmpm.simulate(scene, params, state, progress=False)
    dt = jaxmpm.run.planning.host_cfl_step(scene, params, state)
    bound = scene.grid.h / dt**2
    from jaxmpm.run.planning import acceleration_bound

    ok = params.__class__(**{**params.__dict__, "gravity": params.gravity * 0 + jax_array([0.0, -0.99 * bound])})
    acceleration_bound(scene, ok, state)
    over = params.__class__(**{**params.__dict__, "gravity": params.gravity * 0 + jax_array([0.0, -1.01 * bound])})
    with pytest.raises(ValueError, match=r"gravity = .* is too large"):
        acceleration_bound(scene, over, state)


def jax_array(values):
    import jax.numpy as jnp

    return jnp.asarray(values)


def test_speed_out_of_scale_is_warned_before_and_explained_alike_with_and_without_debug():
    """1e5 m/s on the 1 m grid: a warning before the run names the phase and when it would leave
    the grid; the failure then gets one explanation (the first step where a particle fails, with
    its phase and position) whether the run checks every step (debug) or not."""
    scene, params, state = _impact(**{"phase.disk_a.velocity": [1e5, 1e5]})
    messages = []
    for debug in (False, True):
        with pytest.warns(
            UserWarning,
            match=r"elastic_impact: phase 'disk_a' moves at up to 1\.41e\+05 m/s: unstopped, it "
            r"would leave the grid through a face without a wall at t = .* before t_end = 3 s",
        ):
            with pytest.raises(FloatingPointError) as info:
                jaxmpm.simulate(scene, params, state, progress=False, debug=debug, yes=True)
        messages.append(str(info.value))
    plain, checked = (m.split("; checkify:")[0] for m in messages)
    assert plain == checked
    assert re.match(
        r"elastic_impact: particle \d+ of phase 'disk_\w' is outside the grid at t = .* \(step \d+ of chunk 1", plain
    )
    assert "checkify: step" in messages[1]


# --- the run's PNG ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def brittle_run():
    """The brittle rod (axisymmetric; 80 mm long: a grid 4 times as tall as wide) at its coarsest,
    3 outputs over 10 us."""
    scene = jaxmpm.load_scene("taylor_brittle", resolution=0.3, length=0.08)
    params = jaxmpm.default_params(scene)
    final, history = jaxmpm.simulate(
        scene, params, jaxmpm.init_state(scene, params), t_end=1e-5, n_out=3, progress=False
    )
    return scene, params, history


@pytest.mark.parametrize("field", ["speed", "pressure", "damage", "phase"])
def test_run_figure_has_snapshots_a_colorbar_and_an_energy_panel(brittle_run, field):
    """4 snapshot panels (all 4 outputs), a colorbar (a legend outside the panels for phases) and
    the energy panel, with kinetic, internal and total energy at every output; the narrow
    panels of the tall axisymmetric grid fill most of the figure's width."""
    from jaxmpm.io.plot import run_figure

    scene, params, history = brittle_run
    fig = run_figure(scene, history, field, panels=4, params=params)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    axes = fig.get_axes()
    snaps = [a for a in axes if a.get_title().startswith("t = ")]
    bars = [a for a in axes if a.get_label() == "<colorbar>"]
    energy = [a for a in axes if a.get_ylabel().startswith("energy")]
    assert len(snaps) == 4 and len(energy) == 1
    assert len(bars) == (0 if field == "phase" else 1)
    assert [len(line.get_xdata()) for line in energy[0].get_lines()] == [4, 4, 4]
    assert {t.get_text() for t in energy[0].get_legend().get_texts()} == {"kinetic", "internal", "total"}
    renderer = fig.canvas.get_renderer()
    width = fig.bbox.width
    used = sum(a.get_window_extent(renderer).width for a in snaps + bars)
    assert used > 0.5 * width, (used, width)
    legends = [leg for sub in (fig, *fig.subfigs) for leg in sub.legends]
    assert len(legends) == (1 if field == "phase" else 0)
    for leg in legends + [energy[0].get_legend()]:
        box = leg.get_window_extent(renderer)
        for a in snaps + energy:
            assert not box.overlaps(a.get_window_extent(renderer)), "a legend covers data"


def test_run_png_is_written_with_the_chosen_field(tmp_path, capsys):
    out = tmp_path / "o"
    argv = [
        "run",
        "--opt",
        "resolution=0.25",
        "--t-end",
        "0.2",
        "--n-out",
        "2",
        "--out",
        str(out),
        "--no-progress",
        "--restart-every",
        "0",
        "--plot-field",
        "pressure",
    ]
    assert cli.main(argv) == 0
    png = out / "elastic_impact.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv[:-2] + ["--plot-field", "heat"])
    assert exit_.value.code == 2
    assert "--plot-field: invalid choice: 'heat'" in capsys.readouterr().err


def test_state_plot_of_a_tall_grid_is_not_wider_than_its_panels_need(brittle_run, tmp_path):
    """plot_state's two panels (phases, damage) of the tall axisymmetric grid: the figure is no
    wider than the panels' aspect asks (it was 13 x 9 in for two panels of 2.2 x 9 in)."""
    from PIL import Image

    from jaxmpm.io.plot import plot_state

    scene, params, history = brittle_run
    last = jaxmpm.io.plot.jax_tree_index(history, -1)
    png = plot_state(scene, last, tmp_path / "s.png")
    w, h = Image.open(png).size
    assert w < h


# --- python -m calibration synthetic --out ----------------------------------------------------


class _TinyModel:
    """A stand-in for the synthetic scene's model (observables smooth in theta, identifiable), so
    that the command's writing is checked in a second rather than the scene's minutes."""

    class scene:
        name, t_end = "tiny", 1e-6

    class state:
        x = __import__("numpy").zeros((3, 1))

    n_steps = 1

    @classmethod
    def build(cls):
        return cls()

    @staticmethod
    def observables(theta):
        import jax.numpy as jnp

        return jnp.stack([theta[0], theta[1], theta[0] + 2 * theta[1]])


def test_synthetic_writes_its_result_into_out(tmp_path, capsys, monkeypatch):
    import json

    import calibration.synthetic
    from calibration.__main__ import main

    monkeypatch.setattr(calibration.synthetic, "DebrisInWaterModel", _TinyModel)
    out = tmp_path / "syn"
    assert main(["synthetic", "--out", str(out), "--iterations", "20", "--no-progress"]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["truth"] == {"C_d": 1.0, "C_h": 0.15} and result["start"] == {"C_d": 2.0, "C_h": 0.3}
    assert result["recovered"]["C_d"] == pytest.approx(1.0, rel=1e-6)
    assert result["recovered"]["C_h"] == pytest.approx(0.15, rel=1e-6)
    assert str(out / "result.json") in capsys.readouterr().out
    assert main(["synthetic", "--out", str(out), "--no-progress"]) == 2  # never over a previous result
    assert "the folder exists and is not empty" in capsys.readouterr().err


# --- the project's own physics documentation -------------------------------------------------


def test_physics_doc_names_every_equation_label_and_functions_that_exist():
    """docs/physics.md (shipped with the repository, not beside it) defines E1-E15 and maps each
    to `module:function` names that exist in the package; the README points to it."""
    import importlib
    import pathlib

    root = pathlib.Path(__file__).parents[1]
    text = (root / "docs" / "physics.md").read_text()
    cited = set()
    for path in (root / "jaxmpm").rglob("*.py"):
        cited |= set(re.findall(r"\bE(1[0-5]|[1-9])\b", path.read_text()))
    table = text.split("## 6. Where each equation is implemented")[1]
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| (E\d+|2\.1|2\.3|3) \|[^|]*\| (.*) \|$", table, re.M)}
    for label in [f"E{k}" for k in range(1, 16)]:
        assert f"({label})" in text, f"{label} is not defined"
        assert label in rows, f"{label} has no implementation row"
    assert {f"E{k}" for k in map(int, cited)} <= set(rows)
    for where in rows.values():
        for module, name in re.findall(r"`([\w.]+):(\w+)`", where):
            assert hasattr(importlib.import_module(f"jaxmpm.{module}"), name), f"{module}:{name}"
    readme = (root / "README.md").read_text()
    assert "docs/physics.md" in readme and "../shared/design/PHYSICS.md" not in readme


def test_notebook_extra_brings_ipywidgets_and_the_readme_says_so():
    """tqdm's notebook progress bars need ipywidgets ("IProgress not found" without it)."""
    import pathlib

    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    root = pathlib.Path(__file__).parents[1]
    extras = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    names = {re.split(r"[<>=~!; ]", req)[0] for req in extras["notebook"]}
    assert {"ipywidgets", "ipykernel"} <= names and names & {"notebook", "jupyterlab"}
    assert '".[notebook]"' in (root / "README.md").read_text()
