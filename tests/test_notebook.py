"""The scripting notebook (examples/scripting.ipynb) runs from top to bottom in a fresh kernel, as a user would run
it, and shows what it says it shows: the run's verdicts, the plots, the condition a hand-written controller
violates, and a 50-run campaign (issue 37)."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "scripting.ipynb"


def test_the_notebook_is_kept_without_outputs():
    cells = json.loads(NOTEBOOK.read_text())["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert code and all(c["outputs"] == [] and c["execution_count"] is None for c in code)


@pytest.mark.slow
def test_the_notebook_runs_in_a_fresh_kernel_and_shows_its_findings(tmp_path):
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(nb, timeout=240, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError, with the cell and its traceback, if a cell fails
    texts, images = [], []
    for cell in nb.cells:
        for output in cell.get("outputs", []):
            if output.output_type == "stream":
                texts.append(output.text)
            elif output.output_type in ("execute_result", "display_data"):
                texts.append(output.data.get("text/plain", ""))
                if "image/png" in output.data:
                    images.append(base64.b64decode(output.data["image/png"]))
    text = "\n".join(texts)
    assert "'NoHarm': 'holds'" in text  # the one run's verdicts
    assert "StopsWhenClose: violated at" in text and "robot.safety_mode stayed normal" in text
    assert "20 runs," in text and "at 95 % confidence" in text
    # three figures (the run's trace, the sweep, the campaign's verdicts), each a real PNG
    assert len(images) == 3 and all(png.startswith(b"\x89PNG") and len(png) > 10_000 for png in images)
