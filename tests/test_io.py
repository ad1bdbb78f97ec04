"""jaxmpm.io: HDF5 round trip, refusal to overwrite, atomic writes, XDMF validity, plots, summaries."""

import dataclasses
import os
import xml.etree.ElementTree as ET

import jax

jax.config.update("jax_enable_x64", True)

import h5py  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import jaxmpm  # noqa: E402
from jaxmpm import io  # noqa: E402
from jaxmpm.model.state import phase_slices  # noqa: E402


@pytest.fixture(scope="module")
def run():
    """A tiny 2D run: (scene, params, final, history) with 3 outputs."""
    scene = jaxmpm.load_scene("elastic_impact", resolution=0.25)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    final, history = jaxmpm.simulate(scene, params, state, t_end=0.05, n_out=2, progress=False)
    return scene, params, final, history


@pytest.fixture(scope="module")
def bar():
    """A 1D scene and a one-output history of its initial state (no simulation)."""
    scene = jaxmpm.load_scene("vibrating_bar", cells=10)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    return scene, params, jax.tree.map(lambda a: a[None], state)


def test_round_trip(run, tmp_path):
    scene, params, _, history = run
    h5, xdmf = io.write(tmp_path / "r.h5", scene, history, params=params)
    assert h5.is_file() and xdmf == tmp_path / "r.xdmf" and xdmf.is_file()
    scene2, hist2 = io.read(h5)
    assert scene2 == scene
    for name in ("t", "x", "v", "stress", "F", "volume", "mass", "energy"):
        a, b = np.asarray(getattr(history, name)), getattr(hist2, name)
        assert b.dtype == a.dtype == np.float64, name
        np.testing.assert_array_equal(b, a, err_msg=name)
    assert hist2.C is None
    assert hist2.t.shape == (3,) and hist2.t[-1] == pytest.approx(0.05)


def test_layout_and_metadata(run, tmp_path):
    scene, params, _, history = run
    h5, _ = io.write(tmp_path / "m.h5", scene, history, params=params)
    with h5py.File(h5, "r") as f:
        assert f.attrs["jaxmpm_version"] == jaxmpm.__version__
        assert f.attrs["dtype"] == "float64" and f.attrs["dim"] == 2 and f.attrs["n_out"] == 2
        assert f["scene"].asstr()[()] == jaxmpm.scene_to_toml(scene)
        assert sorted(k for k in f if k.startswith("t")) == ["t0000", "t0001", "t0002"]
        assert f["t0001"].attrs["time"] == pytest.approx(0.025)
        expect = {"x": "m", "v": "m/s", "volume": "m^2", "mass": "kg/m", "stress": "Pa", "energy": "J/kg", "F": "1"}
        for phase, sl in zip(scene.phases, phase_slices(scene)):
            g = f["t0002"][phase.name]
            for name, unit in expect.items():
                assert g[name].attrs["units"] == unit, name
            np.testing.assert_array_equal(g["stress"][()], np.asarray(history.stress[2, sl]))
            x3 = g["x3"][()]
            assert x3.shape == (sl.stop - sl.start, 3)
            np.testing.assert_array_equal(x3[:, :2], np.asarray(history.x[2, sl]))
            assert not x3[:, 2].any()
            assert g["eps_ps"].attrs["units"] == "1" and g["damage"].attrs["units"] == "1"
            assert g["pressure"].attrs["units"] == "Pa"
            for name in ("eps_ps", "damage", "pressure"):
                np.testing.assert_array_equal(g[name][()], np.asarray(getattr(history, name)[2, sl]))
        assert float(f["params/phases/disk_a/E"][()]) == float(params.phases["disk_a"]["E"])
        assert float(f["params/cfl"][()]) == float(params.cfl)


def test_refuses_to_overwrite(run, tmp_path):
    scene, _, _, history = run
    h5, xdmf = io.write(tmp_path / "o.h5", scene, history)
    before = (h5.read_bytes(), xdmf.read_bytes())
    with pytest.raises(FileExistsError, match="overwrite=True") as e:
        io.write(h5, scene, jax.tree.map(lambda a: a[:1], history))
    assert str(h5) in str(e.value)
    assert (h5.read_bytes(), xdmf.read_bytes()) == before
    h5.unlink()  # the XDMF alone also blocks the write, and no .h5 appears
    with pytest.raises(FileExistsError, match="o.xdmf"):
        io.write(h5, scene, history)
    assert not h5.exists()


def test_overwrite_true_replaces(run, tmp_path):
    scene, _, _, history = run
    h5, _ = io.write(tmp_path / "w.h5", scene, history)
    io.write(h5, scene, jax.tree.map(lambda a: a[-1:], history), overwrite=True)
    _, hist2 = io.read(h5)
    assert hist2.x.shape[0] == 1
    np.testing.assert_array_equal(hist2.x[0], np.asarray(history.x[-1]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.h5", "w.xdmf"]


@pytest.mark.parametrize("stage", ["_pad3", "_xdmf_text"])
def test_interrupted_write_leaves_no_file(run, tmp_path, monkeypatch, stage):
    scene, _, _, history = run

    def boom(*a):
        raise RuntimeError("interrupted")

    monkeypatch.setattr(io, stage, boom)
    with pytest.raises(RuntimeError, match="interrupted"):
        io.write(tmp_path / "i.h5", scene, history)
    assert list(tmp_path.iterdir()) == []


def test_bad_input(run, bar, tmp_path):
    scene, _, _, history = run
    with pytest.raises(ValueError, match=r"\.h5"):
        io.write(tmp_path / "x.txt", scene, history)
    with pytest.raises(ValueError, match="particles"):
        io.write(tmp_path / "x.h5", bar[0], history)
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["a"] = 1
    with pytest.raises(ValueError, match="not a jaxmpm output"):
        io.read(tmp_path / "other.h5")
    with pytest.raises(FileNotFoundError):
        io.read(tmp_path / "missing.h5")


def test_one_state_and_1d(bar, tmp_path):
    scene, params, history = bar
    state = jax.tree.map(lambda a: a[0], history)
    h5, _ = io.write(tmp_path / "bar.h5", scene, state, params=params)
    scene2, hist2 = io.read(h5)
    assert scene2 == scene and hist2.x.shape == (1, state.x.shape[0], 1)
    np.testing.assert_array_equal(hist2.x[0], np.asarray(state.x))
    with h5py.File(h5, "r") as f:
        assert f["t0000/bar/x3"].shape == (state.x.shape[0], 3)
        assert f["t0000/bar/mass"].attrs["units"] == "kg/m^2"


def _check_xdmf(xdmf, h5, n_times, phases):
    root = ET.parse(xdmf).getroot()
    assert root.tag == "Xdmf" and root.get("Version") in ("2.0", "3.0")
    series = root.find("Domain/Grid")
    assert series.get("GridType") == "Collection" and series.get("CollectionType") == "Temporal"
    steps = series.findall("Grid")
    assert len(steps) == n_times
    with h5py.File(h5, "r") as f:
        times = [float(step.find("Time").get("Value")) for step in steps]
        assert times == [float(f[f"t{i:04d}"].attrs["time"]) for i in range(n_times)]
        n_refs = 0
        for step in steps:
            grids = step.findall("Grid")
            assert [g.get("Name") for g in grids] == phases
            for g in grids:
                assert g.find("Topology").get("TopologyType") == "Polyvertex"
                n = int(g.find("Topology").get("NumberOfElements"))
                dims = g.find("Geometry/DataItem").get("Dimensions").split()
                assert dims == [str(n), "3"] and g.find("Geometry").get("GeometryType") == "XYZ"
        for item in root.iter("DataItem"):
            if item.get("Format") != "HDF":
                continue
            name, _, ref = item.text.strip().partition(":")
            assert name == h5.name
            assert ref in f, ref
            assert list(f[ref].shape) == [int(s) for s in item.get("Dimensions").split()], ref
            n_refs += 1
        assert n_refs > 0


def test_xdmf_references_existing_datasets(run, bar, tmp_path):
    scene, _, _, history = run
    h5, xdmf = io.write(tmp_path / "x.h5", scene, history)
    _check_xdmf(xdmf, h5, 3, ["disk_a", "disk_b"])
    scene1, _, hist1 = bar
    h5, xdmf = io.write(tmp_path / "bar.h5", scene1, hist1)
    _check_xdmf(xdmf, h5, 1, ["bar"])


def test_plot_state(run, bar, tmp_path):
    scene, _, final, _ = run
    png = io.plot_state(scene, final, tmp_path / "p.png")
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(FileExistsError, match="overwrite"):
        io.plot_state(scene, final, png)
    assert png.read_bytes() == data
    io.plot_state(scene, final, png, overwrite=True)
    scene1, _, hist1 = bar
    assert io.plot_state(scene1, jax.tree.map(lambda a: a[0], hist1), tmp_path / "bar.png").stat().st_size > 0
    with pytest.raises(ValueError, match="one State"):
        io.plot_state(scene1, hist1, tmp_path / "bad.png")
    assert sorted(os.listdir(tmp_path)) == ["bar.png", "p.png"]


def test_plot_state_adds_a_damage_panel_where_material_has_failed(run, tmp_path):
    """The crack pattern: with damaged particles the picture has a second panel (twice as wide)."""
    import struct

    scene, _, final, _ = run
    width = lambda path: struct.unpack(">I", path.read_bytes()[16:20])[0]  # PNG IHDR width
    intact = io.plot_state(scene, final, tmp_path / "intact.png")
    broken = dataclasses.replace(final, damage=final.damage.at[::2].set(1.0))
    cracked = io.plot_state(scene, broken, tmp_path / "cracked.png")
    assert width(cracked) > 1.8 * width(intact)


def test_summary(run, tmp_path):
    scene, params, _, history = run
    h5, _ = io.write(tmp_path / "s.h5", scene, history, params=params)
    text = io.summary(h5)
    n = [sl.stop - sl.start for sl in phase_slices(scene)]
    assert "elastic_impact" in text and "3 times" in text and "0.05 s" in text
    assert "disk_a" in text and f"{n[0]} particles" in text and "disk_b" in text
    mass = float(jaxmpm.diagnostics.total_mass(jax.tree.map(lambda a: a[0], history)))
    assert f"{mass:.6g}" in text
    ke = float(jaxmpm.diagnostics.kinetic_energy(jax.tree.map(lambda a: a[-1], history)))
    assert f"{ke:.6g}" in text


def test_3d_apic_round_trip(tmp_path):
    from jaxmpm.scenes import basic

    scene = basic.mpm88(n_grid=8, dim=3)
    params = jaxmpm.default_params(scene)
    state = jaxmpm.init_state(scene, params)
    h5, xdmf = io.write(tmp_path / "c.h5", scene, state, params=params)
    scene2, hist2 = io.read(h5)
    assert scene2 == scene
    np.testing.assert_array_equal(hist2.C[0], np.asarray(state.C))
    np.testing.assert_array_equal(hist2.x[0], np.asarray(state.x))
    _check_xdmf(xdmf, h5, 1, ["fluid"])
    with h5py.File(h5, "r") as f:
        assert "x3" not in f["t0000/fluid"] and f["t0000/fluid/C"].attrs["units"] == "1/s"
    assert io.plot_state(scene, state, tmp_path / "c.png").is_file()


# ----------------------------------------------------------------------------------- bad files and bad input
def _restart_file(scene, params, history, path):
    from jaxmpm import restart

    state = jax.tree.map(lambda a: a[0], history)
    restart.save(path, scene, params, state, [state], t0=0.0, t_end=0.05, n_out=2, next_out=0, chunk=5, dt=None)
    return path


def test_read_names_a_file_that_is_not_an_output_file(run, tmp_path):
    """A text file, a truncated file, a directory or a restart file: a ValueError naming the path
    and what it is, never an h5py OSError without the path or an IndexError."""
    scene, params, _, history = run
    text = tmp_path / "notes.h5"
    text.write_text("not HDF5\n")
    h5, _ = io.write(tmp_path / "good.h5", scene, history)
    cut = tmp_path / "cut.h5"
    cut.write_bytes(h5.read_bytes()[:2000])
    rst = _restart_file(scene, params, history, tmp_path / "run.restart.h5")
    folder = tmp_path / "folder.h5"
    folder.mkdir()
    for bad, what in (
        (text, "is not a readable HDF5 file"),
        (cut, "is not a readable HDF5 file"),
        (rst, "is a jaxmpm restart file, not an output file"),
        (folder, "is a directory"),
    ):
        for fn in (io.read, io.summary):
            with pytest.raises(ValueError, match=what) as e:
                fn(bad)
            assert str(bad) in str(e.value), (fn, bad)
    with h5py.File(tmp_path / "empty.h5", "w") as f:
        f.create_dataset("scene", data=jaxmpm.scene_to_toml(scene))
    for fn in (io.read, io.summary):
        with pytest.raises(ValueError, match="empty.h5 holds no output time group /t0000"):
            fn(tmp_path / "empty.h5")


def test_read_names_a_missing_group_or_dataset(run, tmp_path):
    scene, _, _, history = run
    h5, _ = io.write(tmp_path / "o.h5", scene, history)
    with h5py.File(h5, "r+") as f:
        del f["t0001/disk_b"]
    for fn in (io.read, io.summary):
        with pytest.raises(ValueError, match="o.h5 has no group /t0001/disk_b"):
            fn(h5)
    h5, _ = io.write(tmp_path / "f.h5", scene, history)
    with h5py.File(h5, "r+") as f:
        del f["t0002/disk_a/F"]
    with pytest.raises(ValueError, match="f.h5 has no dataset /t0002/disk_a/F"):
        io.read(h5)
    h5, _ = io.write(tmp_path / "s.h5", scene, history)
    with h5py.File(h5, "r+") as f:
        del f["t0001/disk_a/v"]
        f["t0001/disk_a/v"] = np.zeros((3, 2))
    with pytest.raises(ValueError, match=r"s.h5:/t0001/disk_a/v has shape \(3, 2\)"):
        io.read(h5)
    with h5py.File(h5, "r+") as f:
        del f["t0002"].attrs["time"]
    for fn in (io.read, io.summary):
        with pytest.raises(ValueError, match="s.h5 has no attribute 'time' on /t0002"):
            fn(h5)


def test_write_checks_every_field_against_the_scene(run, tmp_path):
    """Not only x: a field with the wrong particle count is refused, and nothing is written."""
    scene, _, _, history = run
    short_F = dataclasses.replace(history, F=history.F[:, :10])
    with pytest.raises(
        ValueError,
        match=r"history.F has shape \(3, 10, 2, 2\): the scene 'elastic_impact' has \d+ "
        r"particles in 2D and needs \(3, \d+, 2, 2\)",
    ):
        io.write(tmp_path / "f.h5", scene, short_F)
    with pytest.raises(ValueError, match=r"history.damage has shape"):
        io.write(tmp_path / "f.h5", scene, dataclasses.replace(history, damage=history.damage[0]))
    with pytest.raises(ValueError, match=r"history.t has shape \(2,\)"):
        io.write(tmp_path / "f.h5", scene, dataclasses.replace(history, t=history.t[:2]))
    with pytest.raises(ValueError, match="history = NoneType is invalid: allowed a jaxmpm.State"):
        io.write(tmp_path / "f.h5", scene, None)
    with pytest.raises(ValueError, match="scene = str is invalid: allowed a jaxmpm.Scene"):
        io.write(tmp_path / "f.h5", "elastic_impact", history)
    assert list(tmp_path.iterdir()) == []


def test_overwrite_never_replaces_a_directory(run, tmp_path):
    """overwrite=True with a directory where the .h5 (or .xdmf) goes: refused before anything is
    renamed, so no .xdmf appears that points at an .h5 that is not there."""
    scene, _, _, history = run
    (tmp_path / "d.h5").mkdir()
    for overwrite in (False, True):
        with pytest.raises(FileExistsError, match="d.h5 is a directory: refusing to replace it"):
            io.write(tmp_path / "d.h5", scene, history, overwrite=overwrite)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.h5"]
    (tmp_path / "e.xdmf").mkdir()
    with pytest.raises(FileExistsError, match="e.xdmf is a directory"):
        io.write(tmp_path / "e.h5", scene, history, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.h5", "e.xdmf"]
    (tmp_path / "p.png").mkdir()
    with pytest.raises(FileExistsError, match="p.png is a directory"):
        io.plot_state(scene, jax.tree.map(lambda a: a[-1], history), tmp_path / "p.png", overwrite=True)


def test_the_h5_is_renamed_before_the_xdmf(run, tmp_path, monkeypatch):
    """Should replacing the .h5 fail, the .xdmf beside it is the old one, intact."""
    scene, _, _, history = run
    h5, xdmf = io.write(tmp_path / "o.h5", scene, history)
    before = (h5.read_bytes(), xdmf.read_bytes())
    real = os.replace

    def failing(src, dst):
        if os.fspath(dst).endswith(".h5"):
            raise OSError("disk full (simulated)")
        real(src, dst)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="disk full"):
        io.write(h5, scene, jax.tree.map(lambda a: a[:1], history), overwrite=True)
    assert (h5.read_bytes(), xdmf.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.h5", "o.xdmf"]


def test_a_file_in_place_of_a_folder_is_named(run, tmp_path):
    scene, _, final, history = run
    (tmp_path / "afile").write_text("x")
    with pytest.raises(FileExistsError, match=r"cannot write .*afile/sub/o.h5: .*afile is a file, not a folder"):
        io.write(tmp_path / "afile" / "sub" / "o.h5", scene, history)
    with pytest.raises(FileExistsError, match=r"cannot write .*afile/p.png: .*afile is a file, not a folder"):
        io.plot_state(scene, final, tmp_path / "afile" / "p.png")
    assert (tmp_path / "afile").read_text() == "x"


def test_plot_state_checks_the_state_and_the_suffix(run, bar, tmp_path):
    scene, _, final, _ = run
    scene1, _, hist1 = bar
    with pytest.raises(
        ValueError, match=r"state has \d+ particles in 2D: the scene 'vibrating_bar' has \d+ particles in 1D"
    ):
        io.plot_state(scene1, final, tmp_path / "a.png")
    with pytest.raises(ValueError, match=r"state.v has shape"):
        io.plot_state(scene, dataclasses.replace(final, v=final.v[:5]), tmp_path / "a.png")
    with pytest.raises(ValueError, match=r"path = '.*a.jpg' is invalid: allowed a file name ending in .png"):
        io.plot_state(scene, final, tmp_path / "a.jpg")
    with pytest.raises(ValueError, match="state = NoneType is invalid"):
        io.plot_state(scene, None, tmp_path / "a.png")
    assert list(tmp_path.iterdir()) == []


def test_load_scene_names_a_file_that_is_not_text(run, tmp_path):
    scene, _, _, history = run
    h5, _ = io.write(tmp_path / "o.h5", scene, history)
    toml = tmp_path / "o.toml"
    toml.write_bytes(h5.read_bytes())
    with pytest.raises(ValueError, match=r"scene file '.*o.toml' is not a TOML scene file: it is not UTF-8 text"):
        jaxmpm.load_scene(toml)
    with pytest.raises(ValueError, match=r"scene file '.*o.h5' is not a TOML scene file"):
        jaxmpm.load_scene(str(h5))
