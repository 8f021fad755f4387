"""Figures of tactile scans (matplotlib, imported lazily)."""

from __future__ import annotations

import numpy as np

from .._validate import as_count, as_float_array, as_name, as_positive_float
from ..errors import ValidationError

__all__ = ["plot_scan"]


def plot_scan(frames, *, every: int = 2, n_shown: int = 60, columns: int = 12, title: str | None = None,
              max_value: float = 4095.0):
    """Tile the frames of one scan, as in Fig. 4 of "Dynamic Tactile Sensing for Object
    Identification" (bright = high pressure; the frame number is above each tile).

    Parameters
    ----------
    frames : (n_frames, rows, cols) array
    every : int
        Show every ``every``-th frame (the paper shows every second frame).
    n_shown : int
        Number of frames shown (the paper: 60).
    columns : int
        Frames per row of the figure.

    Returns
    -------
    matplotlib.figure.Figure
    """
    F = as_float_array(frames, "frames", expected="(n_frames, rows, cols) pressures")
    if F.ndim != 3 or 0 in F.shape:
        raise ValidationError(f"frames must be (n_frames, rows, cols), got {F.shape}")
    every = as_count(every, "every", max=100_000)
    n_shown = as_count(n_shown, "n_shown", max=1000, why="one tile per frame shown")
    columns = as_count(columns, "columns", max=1000)
    title = as_name(title, "title")
    max_value = as_positive_float(max_value, "max_value")
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    idx = np.arange(0, F.shape[0], max(1, int(every)))[: max(1, int(n_shown))]
    rows = int(np.ceil(len(idx) / columns))
    head = 0.5 if title else 0.0  # inches kept free above the tiles for the title
    fig, axes = plt.subplots(rows, columns, figsize=(columns * 0.9, rows * 1.05 + head), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, i in zip(axes.ravel(), idx):
        ax.imshow(F[i], cmap="gray", vmin=0, vmax=max_value, interpolation="nearest")
        ax.set_title(str(i), fontsize=6, pad=1)
    fig.tight_layout(pad=0.2, h_pad=0.6, rect=(0, 0, 1, 1 - head / fig.get_figheight()))
    if title:
        fig.suptitle(title, y=1 - 0.1 / fig.get_figheight(), va="top")
    return fig
