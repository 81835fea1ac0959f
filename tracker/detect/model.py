"""The head-point network: a small fully convolutional CenterNet-style heat map.

Design (each choice measured on the 2-core machine, PyTorch 2.13 CPU):

* **Stride 4.** Two stride-2 3x3 convolutions, then three 3x3 convolutions dilated 1, 2 and 4
  (receptive field 63 px: a head of 8-16 px and its neighbours). Heads of 8 px still span two
  output cells, and people in the densest scenes stand at least one template apart, so two
  heads never share a cell. At 1280x720 the forward pass takes about 30 ms with channels-last
  tensors on 2 threads; a stride-2 net cost 4x that.
* **Three output channels** (as CenterNet, Zhou et al. 2019): a heat-map logit whose peaks are
  heads, and the sub-cell offset ``(dx, dy)`` of the head centre from the cell centre in cells,
  so localisation is not quantised to 4 px.
* **Per-image standardisation** of the input (per-channel mean, one global standard deviation):
  ground colour, contrast and lighting differ from scene to scene; the net sees none of that.

Cell ``(i, j)`` of the output is centred on pixel ``(x, y) = (4 j, 4 i)`` (two ``k3 s2 p1``
convolutions), so a head at ``p`` belongs to cell ``round(p / 4)`` and its offset is
``p / 4 - round(p / 4)`` in ``[-0.5, 0.5]``. Only :func:`build_net` needs torch; the target and
decoding helpers are numpy.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

STRIDE = 4
"""Pixels per output cell."""


@dataclass(frozen=True)
class Architecture:
    """Sizes of the network (stored beside its weights; the loader rebuilds from them)."""

    stem: tuple[int, int] = (16, 32)
    width: int = 32
    dilations: tuple[int, ...] = (1, 2, 4)
    stride: int = STRIDE

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Architecture:
        arch = cls(
            stem=tuple(int(v) for v in data["stem"]),
            width=int(data["width"]),
            dilations=tuple(int(v) for v in data["dilations"]),
            stride=int(data["stride"]),
        )
        if arch.stride != STRIDE or len(arch.stem) != 2:
            raise ValueError(f"unsupported architecture {data!r} (stride must be {STRIDE})")
        return arch


def build_net(arch: Architecture | None = None) -> Any:
    """The network as a ``torch.nn.Sequential`` (needs torch: the ``detect`` extra)."""
    from crowdsim.optional import require

    torch = require("torch", "detect", "the head detector")
    nn = torch.nn
    arch = arch or Architecture()

    def block(c_in: int, c_out: int, stride: int = 1, dilation: int = 1) -> list[Any]:
        conv = nn.Conv2d(c_in, c_out, 3, stride, dilation, dilation=dilation, bias=False)
        return [conv, nn.BatchNorm2d(c_out), nn.ReLU(inplace=True)]

    a, b = arch.stem
    layers = block(3, a, 2) + block(a, b, 2)
    c = b
    for d in arch.dilations:
        layers += block(c, arch.width, 1, d)
        c = arch.width
    head = nn.Conv2d(c, 3, 1)
    with torch.no_grad():  # heat prior 0.1 (CenterNet): the loss starts balanced
        head.bias.zero_()
        head.bias[0] = -2.19
    return nn.Sequential(*layers, head)


def standardise(frames: np.ndarray) -> np.ndarray:
    """``(B, H, W, 3)`` uint8 BGR -> ``(B, 3, H, W)`` float32, zero mean per channel and unit
    standard deviation per image."""
    x = np.asarray(frames, dtype=np.float32)
    x = x - x.mean(axis=(1, 2), keepdims=True)
    x /= x.std(axis=(1, 2, 3), keepdims=True) + 1.0
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2))


def padded_size(height: int, width: int) -> tuple[int, int]:
    """The input size rounded up to a multiple of the stride (padding at the bottom/right)."""
    return -(-height // STRIDE) * STRIDE, -(-width // STRIDE) * STRIDE


def heat_sigma(template_px: float) -> float:
    """Standard deviation, in cells, of a head's Gaussian in the target heat map."""
    return max(0.75, float(template_px) / (4.0 * STRIDE))


def targets(
    points: np.ndarray, out_h: int, out_w: int, template_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training targets of one image for heads at ``points (k, 2)`` px.

    Returns ``heat (out_h, out_w)`` float32 (1 at each head's cell, a Gaussian of
    :func:`heat_sigma` around it, the maximum where two overlap), ``cells (m, 2)`` int64
    ``(row, col)`` of the heads inside the map, and ``offsets (m, 2)`` float32 ``(dx, dy)``.

    >>> h, cells, off = targets(np.array([[9.0, 4.4]]), 4, 4, 8)
    >>> cells.tolist(), [round(float(v), 2) for v in off[0]], float(h[1, 2]), float(h[1, 1]) < 1
    ([[1, 2]], [0.25, 0.1], 1.0, True)
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(1)]
    u = pts / STRIDE
    cell = np.rint(u).astype(np.int64)  # (x, y) cells
    inside = (cell[:, 0] >= 0) & (cell[:, 0] < out_w) & (cell[:, 1] >= 0) & (cell[:, 1] < out_h)
    cell, u = cell[inside], u[inside]
    heat = np.zeros((out_h, out_w), np.float32)
    sigma = heat_sigma(template_px)
    r = int(np.ceil(3 * sigma))
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    g = np.exp(-(dx**2 + dy**2) / (2 * sigma**2)).astype(np.float32).ravel()
    ys = (cell[:, 1, None] + dy.ravel()).ravel()
    xs = (cell[:, 0, None] + dx.ravel()).ravel()
    vals = np.tile(g, len(cell))
    ok = (ys >= 0) & (ys < out_h) & (xs >= 0) & (xs < out_w)
    np.maximum.at(heat.reshape(-1), ys[ok] * out_w + xs[ok], vals[ok])
    offsets = (u - cell).astype(np.float32)
    return heat, cell[:, ::-1].copy(), offsets


def decode(
    heat: np.ndarray, offsets: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """Peaks of one heat map (probabilities ``(h, w)``) above ``threshold`` that are the maximum
    of their 3x3 neighbourhood, as ``points (m, 2)`` px and ``scores (m,)``, highest first.

    ``offsets (2, h, w)`` are the predicted sub-cell ``(dx, dy)``.

    >>> heat = np.zeros((3, 4)); heat[1, 2] = 0.9; heat[1, 1] = 0.5
    >>> off = np.zeros((2, 3, 4)); off[:, 1, 2] = (0.25, -0.5)
    >>> pts, s = decode(heat, off, 0.3)
    >>> pts.tolist(), s.tolist()
    ([[9.0, 2.0]], [0.9])
    """
    from scipy.ndimage import maximum_filter

    peak = (heat >= threshold) & (heat == maximum_filter(heat, size=3, mode="constant"))
    rows, cols = np.nonzero(peak)
    scores = heat[rows, cols]
    order = np.argsort(-scores, kind="stable")
    rows, cols, scores = rows[order], cols[order], scores[order]
    dx = np.clip(offsets[0, rows, cols], -0.5, 0.5)
    dy = np.clip(offsets[1, rows, cols], -0.5, 0.5)
    pts = np.stack([(cols + dx) * STRIDE, (rows + dy) * STRIDE], axis=1).astype(np.float64)
    return pts, scores.astype(np.float64)
