"""Executes notebooks of this folder in place at their committed setting, from the repository
root, and strips stderr streams (progress bars) from the saved outputs.

    python experiments/execute.py quickstart wabe_study gan_study speed_vs_accuracy
"""

from __future__ import annotations

import sys

import nbclient
import nbformat


def execute(name: str, timeout: int = 900) -> None:
    path = f"experiments/{name}.ipynb"
    book = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(book, timeout=timeout, kernel_name="python3",
                            resources={"metadata": {"path": "."}}).execute()
    for cell in book.cells:
        if cell.cell_type == "code":
            cell.outputs = [o for o in cell.get("outputs", []) if not (
                o.get("output_type") == "stream" and o.get("name") == "stderr")]
    nbformat.write(book, path)


if __name__ == "__main__":
    for notebook in sys.argv[1:] or ("quickstart",):
        execute(notebook)
        print("executed", notebook, flush=True)
