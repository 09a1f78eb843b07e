"""The notebooks run end to end at their small budget, headless, and each draws at least one picture.

Each notebook reads ``SB3_EPS_NOTEBOOK_BUDGET`` in its first code cell; here it is ``small``, and its files go to a
temporary ``SB3_EPS_NOTEBOOK_OUTPUT``. The kernel is this interpreter's: a kernelspec written into a temporary
Jupyter path, so neither a ``python3`` kernel elsewhere on the machine (the one ipykernel installs runs whatever
``python`` is first on PATH) nor an installed copy of the package is used instead of this checkout.
"""

from __future__ import annotations

import os
from pathlib import Path

import nbformat
import pytest
from ipykernel.kernelspec import install as install_kernelspec
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
KERNEL = "sb3-eps-tests"


@pytest.fixture(scope="module")
def kernel_environment(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    prefix = tmp_path_factory.mktemp("jupyter")
    install_kernelspec(kernel_name=KERNEL, prefix=str(prefix))  # argv: this interpreter, -m ipykernel_launcher
    return {
        "JUPYTER_PATH": str(prefix / "share" / "jupyter"),
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
        "SB3_EPS_NOTEBOOK_BUDGET": "small",
    }


def test_there_are_three_notebooks() -> None:
    assert [path.name for path in NOTEBOOKS] == [
        "01_quickstart.ipynb",
        "02_inside_eps.ipynb",
        "03_compare.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda path: path.stem)
def test_notebook_runs_at_its_small_budget(
    path: Path, kernel_environment: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    notebook = nbformat.read(path, as_version=4)
    first_code = next(cell for cell in notebook.cells if cell.cell_type == "code")
    assert "BUDGET = os.environ.get(\"SB3_EPS_NOTEBOOK_BUDGET\"" in first_code.source
    for name, value in {**kernel_environment, "SB3_EPS_NOTEBOOK_OUTPUT": str(tmp_path)}.items():
        monkeypatch.setenv(name, value)
    # The test suite's Agg backend would hide the figures: the kernel chooses its inline one.
    monkeypatch.delenv("MPLBACKEND", raising=False)
    client = NotebookClient(
        notebook,
        kernel_name=KERNEL,
        timeout=300,
        resources={"metadata": {"path": str(path.parent)}},
    )
    before = sorted(path.parent.rglob("*"))
    client.execute()  # raises CellExecutionError on the first failing cell
    outputs = [output for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs]
    errors = [output for output in outputs if output.output_type == "error"]
    assert not errors, errors
    pictures = [output for output in outputs if "image/png" in output.get("data", {})]
    assert pictures, f"{path.name} drew no picture"
    assert sorted(path.parent.rglob("*")) == before, "the notebook wrote beside itself, not into its OUTPUT"
