from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[2] / "notebooks" / "mental_imagery.ipynb"


@pytest.mark.slow
def test_mental_imagery_notebook_runs():
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(
        notebook,
        timeout=1200,
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOK.parent)}},
    ).execute()
    outputs = notebook.cells[-1].outputs
    assert outputs and "psnr_top_down_db" in outputs[0]["data"]["text/plain"]
