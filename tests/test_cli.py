"""The `jaxmpm` command: run, scenes, materials, show, refusal to overwrite, errors without tracebacks."""

import os
import re
import subprocess
import sys

import jax

jax.config.update("jax_enable_x64", True)

import pytest  # noqa: E402

import jaxmpm  # noqa: E402
from jaxmpm import cli, io  # noqa: E402

TINY = ["--t-end", "0.05", "--n-out", "2", "--set", "grid.cells=[16,16]", "--set", "grid.h=0.0625", "--no-progress"]


def _outputs(folder, name="elastic_impact"):
    return [folder / f"{name}{ext}" for ext in (".h5", ".xdmf", ".png")]


@pytest.fixture
def saved(tmp_path):
    """An .h5 file of the initial state of a tiny scene (no simulation)."""
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    h5, _ = io.write(tmp_path / "saved.h5", scene, jax.tree.map(lambda a: a[None], state), params=params)
    return h5


def test_run_writes_outputs_and_refuses_second_run(tmp_path, capsys, monkeypatch):
    assert cli.main(["run", "--out", str(tmp_path), "--x64", *TINY]) == 0
    out = capsys.readouterr().out
    files = _outputs(tmp_path)
    for p in files:
        assert p.is_file() and str(p) in out
    assert "mass" in out and "kinetic" in out
    scene, history = io.read(files[0])
    assert scene.grid.cells == (16, 16) and scene.name == "elastic_impact"
    assert history.t.shape == (3,) and history.t[-1] == pytest.approx(0.05)
    before = [p.read_bytes() for p in files]

    def no_simulation(*a, **k):
        raise AssertionError("simulated although the outputs exist")

    monkeypatch.setattr(jaxmpm, "simulate", no_simulation)
    assert cli.main(["run", "--out", str(tmp_path), *TINY]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and str(files[0]) in err and "--overwrite" in err
    assert "Traceback" not in err
    assert [p.read_bytes() for p in files] == before
    monkeypatch.undo()
    assert cli.main(["run", "--out", str(tmp_path), "--overwrite", *TINY]) == 0


def test_a_failed_run_exits_1_and_says_what_its_restart_file_holds(tmp_path, capsys):
    """A disk thrown out of the grid: exit status 1, the particle named, the restart file left with
    a word on what resuming it would do; a second run into the folder names it as interrupted or
    failed."""
    argv = [
        "run",
        "--out",
        str(tmp_path),
        "--no-progress",
        "--opt",
        "resolution=0.25",
        "--t-end",
        "0.05",
        "--set",
        "phase.disk_a.velocity=[-15,0]",
    ]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "particle 0 of phase 'disk_a' is outside the grid at t = " in err
    assert re.search(
        r"\(step \d+ of chunk \d+, chunks of \d+ steps\)", err
    )  # the step it happened at, as --debug names it
    assert f"{tmp_path / 'elastic_impact.restart.h5'} holds the last state saved before the failure" in err
    assert not any(p.exists() for p in _outputs(tmp_path))
    assert cli.main(argv) == 2
    assert "was interrupted or failed" in capsys.readouterr().err


def test_run_refuses_if_any_output_exists(tmp_path, capsys):
    png = _outputs(tmp_path)[2]
    png.write_bytes(b"keep")
    assert cli.main(["run", "--out", str(tmp_path), *TINY]) == 2
    assert str(png) in capsys.readouterr().err
    assert png.read_bytes() == b"keep" and sorted(os.listdir(tmp_path)) == [png.name]


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--set", "grid.foo=1"], ["grid.foo"]),
        (["--set", "phase.disk_z.velocity=[1.0,0.0]"], ["disk_z"]),
        (["--set", "cfl=2.0"], ["cfl"]),
        (["--set", "no_equals_sign"], ["--set", "key=value"]),
        (["--opt", "resolution"], ["--opt key=value (e.g. --opt resolution=0.5)"]),
        (["--opt", "resolution=0.5", "--opt", "resolution=0.25"], ["--opt resolution is given twice (0.5 and '0.25')"]),
        (["--out", ""], ["--out '' is invalid: allowed a folder name"]),
        (["--opt", "res=0.5"], ["res", "resolution"]),
        (["no_such_scene"], ["no_such_scene", "elastic_impact"]),
        (["--opt", "resolution=abc"], ["--opt resolution='abc'", "allowed a number"]),
        (["--opt", "shape=3"], ["--opt shape=3", "allowed a name"]),
        (
            ["debris_cloud", "--opt", "gap=abc"],
            ["gap = 'abc' is invalid", "allowed a finite number >= 0"],
        ),  # default None: untyped
        (["debris_cloud", "--opt", "gap=inf"], ["gap = inf is invalid", "allowed a finite number >= 0"]),
        (["debris_cloud", "--opt", "gap=true"], ["gap = True is invalid", "allowed a finite number >= 0"]),
        (
            ["debris_cloud", "--opt", "gap=-0.001"],
            ["gap = -0.001 is invalid", "allowed a finite number >= 0 m (from the sphere to the plate's top face)"],
        ),
        (["--t-end", "inf"], ["--t-end inf is invalid: allowed a finite time > 0 s"]),
        (["--resume", "somewhere", "--t-end", "5"], ["--t-end is invalid with --resume"]),
        (["--resume", "somewhere", "--set", "t_end=9", "--n-out", "7"], ["--n-out, --set is invalid with --resume"]),
        (["vibrating_bar", "--resume", "somewhere"], ["a scene is invalid with --resume"]),
        (["elastic_impact", "--resume", "somewhere"], ["a scene is invalid with --resume"]),  # the default, named
        (["--resume", "somewhere", "--out", "elsewhere"], ["--out is invalid with --resume", "in DIR"]),
        (["--resume", "somewhere", "--out", "out"], ["--out is invalid with --resume"]),  # the default, named
    ],
)
def test_run_bad_input_exits_2(tmp_path, capsys, argv, words):
    out = [] if "--resume" in argv else ["--out", str(tmp_path)]  # --resume writes into its own DIR
    assert cli.main(["run", *out, "--no-progress", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "Traceback" not in err
    for w in words:
        assert w in err
    assert not tmp_path.exists() or os.listdir(tmp_path) == []


def test_run_refuses_an_out_it_cannot_write_in_before_simulating(tmp_path, capsys, monkeypatch):
    """A folder this user cannot write to (here: every new file there refused, as on a read-only
    disk; chmod would not stop a root user) is found before the run, not when it saves."""
    import jaxmpm.io.files

    real_open = os.open

    def refuse(path, flags, *a):
        if str(path).startswith(str(tmp_path / "ro")) and flags & os.O_CREAT:
            raise PermissionError(13, "Permission denied")
        return real_open(path, flags, *a)

    def no_simulation(*a, **k):
        raise AssertionError("simulated although --out cannot be written")

    monkeypatch.setattr(jaxmpm.io.files.os, "open", refuse)
    monkeypatch.setattr(jaxmpm, "simulate", no_simulation)
    assert cli.main(["run", "--out", str(tmp_path / "ro"), "--no-progress", *TINY]) == 2
    err = capsys.readouterr().err
    assert f"cannot write in {tmp_path / 'ro'}: Permission denied" in err and "Traceback" not in err
    assert os.listdir(tmp_path) == []  # the folder it made for --out is removed again


def test_run_refuses_an_out_that_is_a_file_before_simulating(tmp_path, capsys):
    ofile = tmp_path / "ofile"
    ofile.write_text("keep")
    assert cli.main(["run", "--out", str(ofile), "--no-progress", *TINY]) == 2
    err = capsys.readouterr()
    assert f"--out {ofile} is a file: allowed a folder" in err.err and "particles" not in err.out  # nothing ran
    assert ofile.read_text() == "keep"


def test_run_scene_file(tmp_path, capsys):
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25).replace(name="from_file", t_end=0.05, n_out=1)
    toml = tmp_path / "s.toml"
    toml.write_text(jaxmpm.scene_to_toml(scene))
    assert cli.main(["run", str(toml), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    assert all(p.is_file() for p in _outputs(tmp_path / "o", "from_file"))
    assert io.read(tmp_path / "o" / "from_file.h5")[0] == scene


def test_scenes_lists_builtins(capsys):
    assert cli.main(["scenes"]) == 0
    out = capsys.readouterr().out
    from jaxmpm.scenes import BUILTINS

    for name, b in BUILTINS.items():
        assert name in out and b.summary in out
    assert "elastic_impact" in out


def _library_toml():
    from jaxmpm.materials.library import library_table

    return library_table()


def _read_from(entry, name, model):
    """The sub-table of a library entry that a model's constant is read from (README: the first of
    eos, elastic, strength, thermal, spall, failure that holds it; tait_n, tait_B from tait, and
    for a tait model its rho0 and p0 too; a fluid's K is derived from its eos)."""
    if name.startswith("tait_") or model.split("+")[0] == "tait" and name in entry.get("tait", {}):
        return "tait"
    for sub in ("eos", "elastic", "strength", "thermal", "spall", "failure"):
        if name in entry.get(sub, {}):
            return sub
    return "eos" if name == "K" and "elastic" not in entry else None


@pytest.mark.parametrize(
    "key, model", [("al2024", None), ("concrete", None), ("water", "tait"), ("steel_4340", "hypoelastic")]
)
def test_materials_shows_each_constant_with_its_unit_source_and_verification(key, model, capsys):
    from jaxmpm.materials import library, model_of

    assert cli.main(["materials", key] + (["--model", model] if model else [])) == 0
    out = capsys.readouterr().out
    model = model or library.default_model(key)
    assert f"model: {model}" in out
    rows = {line[2:14].strip(): line for line in out.splitlines() if line.startswith("  ") and "[" not in line}
    entry, values = _library_toml()[key], library.library_constants(key)
    for name, (*_, unit) in model_of(model).constants.items():
        row = rows[name]
        sub = _read_from(entry, name, model)
        assert float(row[14:28]) == pytest.approx(values[name], rel=1e-5)
        assert row[28:].split() == [*unit.split(), sub, "yes" if entry[sub]["verified"] else "NO"]
        assert f"{sub} [{'verified' if entry[sub]['verified'] else 'not verified'}]: {entry[sub]['source']}" in out


def test_materials_lists_each_key_with_the_unverified_tables_its_default_model_reads(capsys):
    from jaxmpm.materials import known_keys, library, model_of

    assert cli.main(["materials"]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()[1:] if line.strip()}
    toml = _library_toml()
    for key in known_keys():
        model = library.default_model(key)
        subs = {_read_from(toml[key], name, model) for name in model_of(model).constants}
        unverified = [sub for sub, t in toml[key].items() if sub in subs and not t["verified"]]
        assert lines[key].split()[1] == model
        assert lines[key].split(None, 2)[2].strip() == (", ".join(unverified) or "-"), key


def test_materials_model_without_a_key_is_refused(capsys):
    assert cli.main(["materials", "--model", "hypoelastic"]) == 2
    assert "--model hypoelastic needs a library key" in capsys.readouterr().err


def test_materials_rejects_an_unknown_key_or_model(capsys):
    assert cli.main(["materials", "unobtainium"]) == 2
    err = capsys.readouterr().err
    assert "unobtainium" in err and "al2024" in err and "Traceback" not in err
    assert cli.main(["materials", "al2024", "--model", "bogus"]) == 2
    assert "bogus" in capsys.readouterr().err


def test_show(saved, tmp_path, capsys):
    assert cli.main(["show", str(saved)]) == 0
    out = capsys.readouterr().out
    assert out.strip() == io.summary(saved).strip()
    assert "elastic_impact" in out and "disk_a" in out
    png = tmp_path / "last.png"
    assert cli.main(["show", str(saved), "--png", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert cli.main(["show", str(saved), "--png", str(png)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert cli.main(["show", str(saved), "--png", str(png), "--overwrite"]) == 0


def test_show_missing_file(tmp_path, capsys):
    assert cli.main(["show", str(tmp_path / "missing.h5")]) == 2
    err = capsys.readouterr().err
    assert "missing.h5" in err and "Traceback" not in err


def test_python_m_jaxmpm_scenes():
    r = subprocess.run([sys.executable, "-m", "jaxmpm", "scenes"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "elastic_impact" in r.stdout


def test_run_refuses_to_start_without_disk_space(tmp_path, monkeypatch, capsys):
    import shutil
    from collections import namedtuple

    from jaxmpm import cli

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**6, 10**6 - 1000, 1000))
    code = cli.main(
        ["run", "--out", str(tmp_path / "o" / "p"), "--no-progress", "--opt", "resolution=0.25", "--t-end", "0.1"]
    )
    assert code == 2
    err = capsys.readouterr().err
    assert "not enough disk space" in err and "MB are free" in err
    assert os.listdir(tmp_path) == []  # the folders it made for --out are gone, nothing is left behind


@pytest.mark.parametrize(
    "name, options, t_end", [("elastic_impact", {"resolution": 0.25}, 0.2), ("taylor_bar", {"resolution": 0.3}, 1e-6)]
)  # axisymmetric: F (n, 3, 3)
def test_output_size_estimate_covers_the_file(tmp_path, name, options, t_end):
    import jaxmpm
    from jaxmpm import io

    scene = jaxmpm.load_scene(name, **options)
    params = jaxmpm.default_params(scene)
    s0 = jaxmpm.init_state(scene, params)
    _, hist = jaxmpm.simulate(scene, params, s0, t_end=t_end, n_out=3, progress=False)
    h5, xdmf = io.write(tmp_path / "a.h5", scene, hist)
    size = h5.stat().st_size + xdmf.stat().st_size
    est = io.estimate_bytes(scene, s0.x.shape[0], 4, s0.x.dtype.itemsize)
    assert size <= est < 3 * size


@pytest.mark.slow
def test_the_readme_python_example_runs_as_written(capsys):
    """README.md's first Python block ("Using it from Python"), executed as written: the run, the
    plan and the compiled gradient, which must be finite and nonzero (a stiffer ball rebounds)."""
    import pathlib
    import re

    import numpy as np

    text = (pathlib.Path(__file__).parents[1] / "README.md").read_text()
    block = re.search(r"## Using it from Python\s+```python\n(.*?)```", text, re.S).group(1)
    namespace = {}
    exec(compile(block, "README.md", "exec"), namespace)
    printed = float(capsys.readouterr().out.split()[-1])
    assert np.isfinite(printed) and printed != 0.0
    assert float(namespace["grad"](2.0e5)) == printed
