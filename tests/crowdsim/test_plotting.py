"""``crowdsim.plotting.plot_trajectories`` (``crowdsim simulate --plot``): what the figure
shows, read from the figure itself."""

from __future__ import annotations

import numpy as np

from crowdsim import plotting
from crowdsim.trajectories import Trajectories


def _drawn(monkeypatch):
    figs = []
    real = plotting.save_figure
    monkeypatch.setattr(
        plotting, "save_figure", lambda fig, path, dpi=120: figs.append(fig) or real(fig, path, dpi)
    )
    return figs


def _corridor(length: float, width: float) -> tuple[Trajectories, np.ndarray]:
    t = np.linspace(0.0, 1.0, 5)[:, None]
    pos = np.stack([np.hstack([t * length, t * length]), np.full((5, 2), [1.0, width - 1])], -1)
    walls = np.array([[0, 0, length, 0, 0.1], [0, width, length, width, 0.1]], np.float64)
    return Trajectories(positions=pos, ids=np.arange(2), dt=0.04), walls


def test_the_last_positions_are_named_in_a_legend(tmp_path, monkeypatch):
    """The black dots were labelled but no legend was drawn: nothing said what they are."""
    figs = _drawn(monkeypatch)
    traj, walls = _corridor(20.0, 5.0)
    plotting.plot_trajectories(traj, walls, tmp_path / "t.png")
    (ax,) = figs[0].axes
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["last positions"]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x (m)", "y (m)")
    assert (tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"


def test_the_figure_takes_the_scenes_shape(tmp_path, monkeypatch):
    """A 20 m x 5 m corridor in the fixed 8 x 6 in figure left half of it white: a long
    scene now gets a wide, low figure and a square one a square figure."""
    figs = _drawn(monkeypatch)
    for length, width in ((20.0, 5.0), (10.0, 10.0)):
        traj, walls = _corridor(length, width)
        plotting.plot_trajectories(traj, walls, tmp_path / f"{length:g}.png")
    (w_long, h_long), (w_square, h_square) = (f.get_size_inches() for f in figs)
    assert h_long / w_long < 0.5
    assert 0.9 < h_square / w_square < 1.3
