"""Figures as PNG: one plain figure helper for every plot, and trajectories over the walls.

Figures are made with matplotlib's object API (:func:`new_figure`), never through pyplot, so
importing or calling this module selects no backend and leaves a notebook user's matplotlib
state alone.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crowdsim.atomic import atomic_path

if TYPE_CHECKING:
    from crowdsim.trajectories import Trajectories


def plot_trajectories(
    traj: Trajectories,
    walls: np.ndarray,
    path: str | os.PathLike[str],
    title: str = "",
    max_tracks: int = 400,
) -> Path:
    """Write a PNG of the walls, up to ``max_tracks`` trajectories and the last positions.

    Parameters
    ----------
    traj : Trajectories
    walls : (m, 5) wall segments ``x0, y0, x1, y1, half_thickness`` in m
    path : output ``.png`` (written to a temporary file, then renamed)
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"plot file must end in .png, got {str(path)!r}")
    # the figure takes the scene's shape (equal axes): a long corridor in an 8 x 6 figure
    # filled half of it with white
    ends = np.asarray(walls, dtype=np.float64).reshape(-1, 5)[:, :4].reshape(-1, 2)
    pts = traj.positions.reshape(-1, 2)  # a view: fmin/fmax skip NaN without a copy
    lo = np.fmin.reduce(np.vstack([ends, np.fmin.reduce(pts, axis=0)[None]]), axis=0)
    hi = np.fmax.reduce(np.vstack([ends, np.fmax.reduce(pts, axis=0)[None]]), axis=0)
    span = hi - lo
    aspect = float(span[1] / span[0]) if span[0] > 0 and span[1] > 0 else 0.75
    fig, ax = new_figure(figsize=(8, float(np.clip(8 * aspect + 1.2, 2.8, 8))))
    for x0, y0, x1, y1, _ in np.asarray(walls).reshape(-1, 5):
        ax.plot([x0, x1], [y0, y1], "k-", lw=1.5)
    pos = traj.positions
    step = max(1, traj.n_agents // max_tracks)
    period = traj.period
    for n in range(0, traj.n_agents, step):
        x, y = pos[:, n, 0].copy(), pos[:, n, 1]
        if period > 0:  # break the line where the agent crosses the seam
            x[1:][np.abs(np.diff(x)) > period / 2] = np.nan
        ax.plot(x, y, "-", lw=0.6, alpha=0.7)
    last = pos[-1][traj.present[-1]]
    ax.scatter(last[:, 0], last[:, 1], s=4, c="k", zorder=3, label="last positions")
    ax.set_aspect("equal")
    ax.legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize="small", frameon=False)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"{traj.n_agents} agents, {(traj.n_steps - 1) * traj.dt:g} s")
    return save_figure(fig, path, dpi=110)


def new_figure(
    figsize: tuple[float, float] = (5.0, 3.6), dpi: int = 120, ncols: int = 1
) -> tuple[Any, Any]:
    """A matplotlib ``Figure`` and its axes (``ncols`` of them), made without pyplot."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    return fig, fig.subplots(1, ncols)


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 120) -> Path:
    """Lay out and write a matplotlib figure atomically; returns the path.

    A figure made through pyplot is closed afterwards (one made by :func:`new_figure` has no
    pyplot state to close).
    """
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=Path(path).suffix.lstrip(".") or "png")
    finally:
        if "matplotlib.pyplot" in sys.modules:
            sys.modules["matplotlib.pyplot"].close(fig)
    return Path(path)
