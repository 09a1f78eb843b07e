"""Helpers for Jupyter: an episode as an inline animation, a strip of its pictures, one picture as a figure; and
:func:`execute_notebook`, which runs the notebooks headless (the tests at a small budget, ``make notebooks`` at full).

``notebooks/01_quickstart.ipynb`` uses them with :func:`sb3_eps.common.evaluation.record_frames`::

    frames, episodes = record_frames(model, "MultiRobotNav-4-v0", frame_every=2)
    Animation(frames, fps=10)      # the cell's value: a looping GIF in the notebook
    filmstrip(frames)              # a static strip of pictures (a PNG, which every notebook viewer shows)

Nothing here imports IPython: :class:`Animation` is displayed through its ``_repr_html_``. Figures are made
without pyplot, so they neither need nor change a matplotlib backend.
"""

from __future__ import annotations

import base64
import io
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import imageio.v2 as imageio
import numpy as np
from matplotlib.figure import Figure


def gif_bytes(frames: Sequence[np.ndarray], fps: float = 20.0, shrink: int = 1) -> bytes:
    """Encode ``rgb_array`` pictures as a looping GIF.

    :param frames: ``(H, W, 3)`` uint8 pictures of one size
    :param fps: frames per second
    :param shrink: keep every ``shrink``-th pixel in both directions (2: a quarter of the bytes, for a notebook
        that is committed with its outputs)
    :return: the GIF file's bytes
    """
    if len(frames) == 0:
        raise ValueError("an animation needs at least one frame")
    if fps <= 0 or shrink < 1:
        raise ValueError(f"fps must be positive and shrink >= 1, got {fps} and {shrink}")
    buffer = io.BytesIO()
    # The Pillow GIF writer takes the frame duration in milliseconds.
    imageio.mimsave(
        buffer,
        [np.asarray(frame, dtype=np.uint8)[::shrink, ::shrink] for frame in frames],
        format="GIF",
        duration=1000.0 / fps,
        loop=0,
    )
    return buffer.getvalue()


class Animation:
    """An episode's pictures shown as a looping GIF where a notebook displays the object.

    :param frames: ``(H, W, 3)`` uint8 pictures of one size
    :param fps: frames per second (the robots decide at 20 Hz: with ``frame_every=2`` pictures, 10 plays in real
        time)
    :param width: displayed width in pixels (None: the pictures' own)
    :param shrink: keep every ``shrink``-th pixel (:func:`gif_bytes`)
    """

    def __init__(self, frames: Sequence[np.ndarray], fps: float = 20.0, width: int | None = None, shrink: int = 1) -> None:
        self.data = gif_bytes(frames, fps, shrink)
        self.n_frames = len(frames)
        self.width = width

    def __repr__(self) -> str:
        return f"Animation({self.n_frames} frames, {len(self.data) / 1e3:.0f} kB GIF)"

    def _repr_html_(self) -> str:
        encoded = base64.b64encode(self.data).decode("ascii")
        width = f' width="{self.width}"' if self.width else ""
        return f'<img src="data:image/gif;base64,{encoded}"{width} alt="episode animation"/>'

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the GIF to ``path`` (its folder is created). :return: the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(self.data)
        return path


def filmstrip(frames: Sequence[np.ndarray], n_pictures: int = 6, title: str | None = None) -> Figure:
    """``n_pictures`` pictures evenly spread over an episode, side by side, each labelled with its index.

    :param frames: the episode's pictures
    :param n_pictures: how many to show (fewer if there are fewer frames)
    :param title: the figure's title
    :return: the figure
    """
    if len(frames) == 0:
        raise ValueError("a filmstrip needs at least one frame")
    chosen = np.unique(np.linspace(0, len(frames) - 1, min(n_pictures, len(frames))).round().astype(int))
    figure = Figure(figsize=(2.6 * len(chosen), 2.9))
    axes = np.atleast_1d(figure.subplots(1, len(chosen)))
    for axis, index in zip(axes, chosen, strict=True):
        axis.imshow(frames[index])
        axis.set_title(f"frame {index}", fontsize="small")
        axis.axis("off")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return figure


def show_picture(picture: np.ndarray, title: str | None = None, size: float = 5.0) -> Figure:
    """One ``rgb_array`` picture as a figure (e.g. ``env.render()`` of a world just reset).

    :param picture: ``(H, W, 3)`` uint8
    :param title: the axis title
    :param size: the figure's height in inches
    :return: the figure
    """
    height, width = picture.shape[:2]
    figure = Figure(figsize=(size * width / height, size))
    axis = figure.subplots()
    axis.imshow(picture)
    axis.axis("off")
    if title:
        axis.set_title(title)
    figure.tight_layout()
    return figure


#: The environment variables a notebook's first cell reads: its budget ("full" or "small") and its output folder.
BUDGET_VARIABLE = "SB3_EPS_NOTEBOOK_BUDGET"
OUTPUT_VARIABLE = "SB3_EPS_NOTEBOOK_OUTPUT"
BUDGETS = ("full", "small")
_KERNEL_NAME = "sb3-eps-this-python"


def execute_notebook(
    path: str | os.PathLike[str],
    budget: str = "small",
    output: str | os.PathLike[str] | None = None,
    timeout: float = 1_800,
) -> Any:
    """Run a notebook of ``notebooks/`` from top to bottom in a kernel of this interpreter, headless.

    The kernel is this interpreter (a kernelspec written to a temporary folder, so neither a ``python3`` kernel found
    elsewhere on the machine nor another installed copy of the package runs instead), with this checkout first on
    ``PYTHONPATH``, in the notebook's folder, with matplotlib's inline backend. Needs the ``dev`` extra (nbclient,
    ipykernel).

    :param path: the ``.ipynb`` file
    :param budget: ``"full"`` (the run its committed outputs come from) or ``"small"`` (seconds: the tests)
    :param output: the folder the notebook writes into (:data:`OUTPUT_VARIABLE`); None: the notebook's default
    :param timeout: seconds a cell may run
    :return: the executed notebook (an ``nbformat`` node); ``nbclient.exceptions.CellExecutionError`` on the first
        failing cell
    """
    import nbformat
    from ipykernel.kernelspec import install
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import AsyncKernelManager
    from jupyter_core.utils import run_sync
    from nbclient import NotebookClient

    if budget not in BUDGETS:
        raise ValueError(f"budget must be one of {BUDGETS}, got {budget!r}")
    path = Path(path).resolve()
    notebook = nbformat.read(path, as_version=4)
    checkout = str(Path(__file__).resolve().parents[1])
    environment = {key: value for key, value in os.environ.items() if key != "MPLBACKEND"}  # inline figures
    environment["PYTHONPATH"] = os.pathsep.join(filter(None, [checkout, os.environ.get("PYTHONPATH")]))
    environment[BUDGET_VARIABLE] = budget
    if output is not None:
        environment[OUTPUT_VARIABLE] = str(Path(output).resolve())
    with tempfile.TemporaryDirectory() as prefix:
        kernel_dir = Path(install(kernel_name=_KERNEL_NAME, prefix=prefix)).parent
        specs = KernelSpecManager(kernel_dirs=[str(kernel_dir)], ensure_native_kernel=False)
        manager = AsyncKernelManager(kernel_name=_KERNEL_NAME, kernel_spec_manager=specs)
        client = NotebookClient(notebook, km=manager, timeout=timeout, resources={"metadata": {"path": str(path.parent)}})
        try:
            client.execute(env=environment)
        finally:  # nbclient shuts down only the kernels it created itself, not one of a manager given to it
            if manager.has_kernel:
                run_sync(manager.shutdown_kernel)(now=True)
    return notebook


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m research.notebook [--budget full] NOTEBOOK...``: execute notebooks and write them back with their
    outputs (``make notebooks`` re-runs all of them at their full budget).

    :return: the exit status
    """
    import argparse
    import time

    import nbformat

    parser = argparse.ArgumentParser(prog="python -m research.notebook", description=main.__doc__)
    parser.add_argument("notebooks", nargs="+", help=".ipynb files, executed in place")
    parser.add_argument("--budget", choices=BUDGETS, default="full")
    parser.add_argument("--output", default=None, help="the folder the notebooks write into")
    args = parser.parse_args(argv)
    for name in args.notebooks:
        start = time.perf_counter()
        kernelspec = nbformat.read(name, as_version=4).metadata.get("kernelspec")
        notebook = execute_notebook(name, args.budget, args.output)
        if kernelspec is not None:  # the file keeps naming the usual kernel, not the temporary one
            notebook.metadata["kernelspec"] = kernelspec
        nbformat.write(notebook, name)
        print(f"{name}: {args.budget} budget, {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
