"""The notebooks run end to end at a small size (JAXMPM_NOTEBOOK_SMALL=1), so they never rot."""

import pathlib

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = sorted((pathlib.Path(__file__).parents[1] / "notebooks").glob("*.ipynb"))


# run with -m slow (the default run stays under 15 minutes on 2 cores)
SLOW = {
    "quickstart",
    "debris_cloud",
    "calibration",
    "materials",
    "multiphase_basics",
    "projectile_concrete",
    "rod_penetration",
    "sandwich_target",
    "taylor_bar",
    "taylor_brittle",
}


@pytest.mark.parametrize(
    "path",
    [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW else p for p in NOTEBOOKS],
    ids=[p.stem for p in NOTEBOOKS],
)
def test_notebook_runs(path, monkeypatch):
    monkeypatch.setenv("JAXMPM_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
    )
    client.execute()
    errors = [
        o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"
    ]
    assert not errors
    assert len(NOTEBOOKS) >= 1
