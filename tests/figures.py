"""The matplotlib figures the code saves as PNG, as objects: what a figure shows (its panels' titles,
labels, legend entries and the data of its lines, images and step plots) checked instead of the
pixels, which depend on the machine's antialiasing."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backend_bases import register_backend
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


class SavedFigures:
    """The figures saved as PNG files while :func:`saved_figures` is active, looked up by the file
    they ended in: by its inode, which a rename keeps (the code writes through a temporary file)."""

    def __init__(self) -> None:
        self._by_file: dict[tuple[int, int], Figure] = {}

    def keep(self, path: str | os.PathLike, figure: Figure) -> None:
        status = os.stat(path)
        self._by_file[status.st_dev, status.st_ino] = figure

    def __getitem__(self, path: str | os.PathLike) -> Figure:
        status = os.stat(path)
        return self._by_file[status.st_dev, status.st_ino]


@contextmanager
def saved_figures() -> Iterator[SavedFigures]:
    """Inside, every figure saved as PNG is still written by matplotlib's Agg canvas, and also kept
    as an object: ``figures[path]`` is the figure whose PNG ``path`` is."""
    figures = SavedFigures()

    class KeepingCanvas(FigureCanvasAgg):
        def print_png(self, filename_or_obj, **kwargs):  # type: ignore[no-untyped-def]
            # print_figure passes other renderers' options (dpi, orientation...) to a canvas not its own
            png = {key: value for key, value in kwargs.items() if key in ("metadata", "pil_kwargs")}
            written = super().print_png(filename_or_obj, **png)
            if isinstance(filename_or_obj, (str, os.PathLike)):  # not a layout's draw into memory
                figures.keep(filename_or_obj, self.figure)
            return written

    register_backend("png", KeepingCanvas)
    try:
        yield figures
    finally:
        register_backend("png", "matplotlib.backends.backend_agg")


def png_size(path: str | Path) -> tuple[int, int]:
    """(width, height) in pixels of a PNG, from its header."""
    header = Path(path).read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    return int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")


def figure_size(figure: Figure, dpi: int = 100) -> tuple[int, int]:
    """(width, height) in pixels of ``figure`` saved at ``dpi`` (sb3_marl.common.files.save_figure's)."""
    width, height = figure.get_size_inches()
    return round(width * dpi), round(height * dpi)


def panels(figure: Figure) -> list[Axes]:
    """The figure's data panels (colour bars left out)."""
    return [ax for ax in figure.axes if ax.get_label() != "<colorbar>"]


def legend_labels(owner: Axes | Figure) -> list[str]:
    """The entries of a panel's legend, or of a figure's own legend."""
    if isinstance(owner, Figure):
        legend = owner.legends[0] if owner.legends else None
    else:
        legend = owner.get_legend()
    return [text.get_text() for text in legend.get_texts()] if legend else []


def line_data(ax: Axes) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The panel's labelled lines: label -> (x, y)."""
    return {
        line.get_label(): (np.asarray(line.get_xdata(), dtype=float), np.asarray(line.get_ydata(), dtype=float))
        for line in ax.get_lines()
        if not line.get_label().startswith("_")
    }
