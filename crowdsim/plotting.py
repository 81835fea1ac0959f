"""Pictures of simulations: trajectories over the scene's walls (matplotlib, PNG)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from crowdsim.atomic import atomic_path
from crowdsim.trajectories import Trajectories


def plot_trajectories(traj: Trajectories, walls: np.ndarray, path: str | os.PathLike[str],
                      title: str = "", max_tracks: int = 400) -> Path:
    """Write a PNG of the walls, up to ``max_tracks`` trajectories and the last positions.

    Parameters
    ----------
    traj : Trajectories
    walls : (m, 5) wall segments ``x0, y0, x1, y1, half_thickness`` in m
    path : output ``.png`` (written to a temporary file, then renamed)
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"plot file must end in .png, got {str(path)!r}")
    fig, ax = plt.subplots(figsize=(8, 6))
    for x0, y0, x1, y1, _ in np.asarray(walls).reshape(-1, 5):
        ax.plot([x0, x1], [y0, y1], "k-", lw=1.5)
    pos = traj.positions
    step = max(1, traj.n_agents // max_tracks)
    for n in range(0, traj.n_agents, step):
        ax.plot(pos[:, n, 0], pos[:, n, 1], "-", lw=0.6, alpha=0.7)
    last = pos[-1][traj.present[-1]]
    ax.scatter(last[:, 0], last[:, 1], s=4, c="k", zorder=3, label="last positions")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"{traj.n_agents} agents, {(traj.n_steps - 1) * traj.dt:g} s")
    return save_figure(fig, path, dpi=110)


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 120) -> Path:
    """Lay out, write atomically and close a matplotlib figure; returns the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)
    return Path(path)
