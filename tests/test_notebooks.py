"""The notebooks run end to end at their small budget, headless, and each draws at least one picture.

:func:`research.notebook.execute_notebook` runs them as ``make notebooks`` does at full budget: a kernel of this
interpreter (not whatever ``python3`` kernel the machine has), this checkout first on ``PYTHONPATH``, the budget
``small`` in ``SB3_EPS_NOTEBOOK_BUDGET`` and a temporary ``SB3_EPS_NOTEBOOK_OUTPUT`` for the files they write.
"""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest

from research.notebook import BUDGET_VARIABLE, execute_notebook

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def _kernels() -> set[int]:
    """:return: the process ids of the kernels this test process started."""
    import psutil

    def is_kernel(child: psutil.Process) -> bool:
        try:
            return "ipykernel_launcher" in " ".join(child.cmdline())
        except (psutil.ZombieProcess, psutil.NoSuchProcess):  # a finished child of an earlier test, not a kernel
            return False

    return {child.pid for child in psutil.Process().children(recursive=True) if is_kernel(child)}


def test_there_are_three_notebooks() -> None:
    assert [path.name for path in NOTEBOOKS] == [
        "01_quickstart.ipynb",
        "02_inside_eps.ipynb",
        "03_compare.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda path: path.stem)
def test_notebook_runs_at_its_small_budget(path: Path, tmp_path: Path) -> None:
    first_code = next(cell for cell in nbformat.read(path, as_version=4).cells if cell.cell_type == "code")
    assert f'BUDGET = os.environ.get("{BUDGET_VARIABLE}", "full")' in first_code.source
    before = sorted(path.parent.rglob("*"))
    kernels_before = _kernels()
    notebook = execute_notebook(path, "small", output=tmp_path, timeout=300)  # raises on a failing cell
    assert _kernels() <= kernels_before, "the notebook's kernel is still running after the execution"
    outputs = [output for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs]
    errors = [output for output in outputs if output.output_type == "error"]
    assert not errors, errors
    assert any("image/png" in output.get("data", {}) for output in outputs), f"{path.name} drew no picture"
    assert sorted(path.parent.rglob("*")) == before, "the notebook wrote beside itself, not into its OUTPUT"


def test_a_budget_must_be_known() -> None:
    with pytest.raises(ValueError, match="budget must be one of"):
        execute_notebook(NOTEBOOKS[0], "huge")
