"""The course in docs/tutorials/: every notebook runs from top to bottom in a fresh kernel (its
exercises' solutions assert what they claim), and shows its pictures inline."""

from __future__ import annotations

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="the test extra installs nbformat, nbclient and ipykernel")
nbclient = pytest.importorskip("nbclient")

TUTORIALS = sorted((Path(__file__).resolve().parents[1] / "docs" / "tutorials").glob("*.ipynb"))


def test_the_course_has_its_five_notebooks():
    assert [p.stem[:2] for p in TUTORIALS] == ["01", "02", "03", "04", "05"]


@pytest.mark.parametrize("path", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_each_notebook_runs_and_shows_its_pictures(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    assert not any(c.get("outputs") for c in nb.cells if c.cell_type == "code")  # stored without outputs
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    pictures = [o for o in outputs if o.output_type in ("display_data", "execute_result")
                and ("image/png" in o.data or "text/html" in o.data)]
    assert pictures, f"{path.name} shows no picture"
    solutions = [c for c in nb.cells if c.cell_type == "code" and c.source.startswith("# Solution")]
    assert solutions and all("assert" in c.source for c in solutions)
