"""The documentation against the code: the getting-started page's code runs as written, every
relative link of README.md and the docs pages points to a file that exists, and the version the
package reports is its distribution's."""

from __future__ import annotations

import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").rglob("*.md"))]


def code_blocks(path, language):
    return re.findall(rf"```{language}\n(.*?)```", path.read_text(), re.S)


def test_getting_started_python_blocks_run_as_written(capsys):
    """Every Python block of docs/getting-started.md, in order, in one namespace (the run, the
    planned steps and the compiled gradient, which must be finite and nonzero)."""
    import numpy as np

    blocks = code_blocks(ROOT / "docs" / "getting-started.md", "python")
    assert len(blocks) >= 2
    namespace = {}
    for block in blocks:
        exec(compile(block, "docs/getting-started.md", "exec"), namespace)
    out = capsys.readouterr().out
    assert "final time" in out
    slope = float(re.search(r"d height / d E = (\S+)", out).group(1))
    assert np.isfinite(slope) and slope != 0.0


def test_getting_started_commands_exist():
    """Every `jaxmpm SUBCOMMAND` of the page's shell blocks is a subcommand the CLI knows."""
    from jaxmpm.cli import build_parser

    parser = build_parser()
    known = set(next(a for a in parser._actions if a.dest == "command").choices)
    used = {
        m.group(1)
        for block in code_blocks(ROOT / "docs" / "getting-started.md", "bash")
        for m in re.finditer(r"^jaxmpm (\w+)", block, re.M)
    }
    assert used and used <= known, used - known


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    """[text](target) links that are not URLs or anchors point to files that exist."""
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+://|#|mailto:", target):
            continue
        if not (page.parent / target.split("#")[0]).exists():
            broken.append(target)
    assert not broken, f"{page.name}: {broken}"


def test_version_is_the_distributions():
    from importlib.metadata import PackageNotFoundError, version

    import jaxmpm

    try:
        expected = version("jaxmpm")
    except PackageNotFoundError:
        expected = "0+unknown"
    assert jaxmpm.__version__ == expected
    out = subprocess.run([sys.executable, "-m", "jaxmpm.cli", "--version"], capture_output=True, text=True)
    if out.returncode == 0:
        assert out.stdout.strip() == f"jaxmpm {expected}"
