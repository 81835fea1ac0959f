"""The term ablation of paper 1's Table 3, as rows of parameter overrides.

``B`` is the appearance term alone; ``Mo`` the motion term ``c_m`` (Eq. 6), ``SP`` spatial
proximity ``C_sp`` (Eq. 9), ``Gr`` grouping ``C_g`` (Eq. 10) and ``NMo`` neighbourhood motion
``c_nm`` (Eq. 7-8). Each combination runs with NCC and with KCF appearance.

>>> [label for label, _ in ABLATION][:2]
['B', 'B+Mo']
>>> ablation_rows()[0]
('B (NCC)', {'zeta': 0.0, 'eta': 0.0, 'w_sp': 0.0, 'w_g': 0.0, 'appearance': 'ncc'})
>>> len(ablation_rows())
12
"""

from __future__ import annotations

from typing import Any

ABLATION: tuple[tuple[str, dict[str, float]], ...] = (
    ("B", {"zeta": 0.0, "eta": 0.0, "w_sp": 0.0, "w_g": 0.0}),
    ("B+Mo", {"eta": 0.0, "w_sp": 0.0, "w_g": 0.0}),
    ("B+Mo+SP", {"eta": 0.0, "w_g": 0.0}),
    ("B+Mo+Gr", {"eta": 0.0, "w_sp": 0.0}),
    ("B+Mo+Gr+NMo", {"w_sp": 0.0}),
    ("B+Mo+SP+Gr+NMo", {}),
)
"""Term combination -> :class:`tracker.bqp.params.BQPParams` overrides switching terms off."""

APPEARANCES: tuple[tuple[str, str], ...] = (("NCC", "ncc"), ("KCF", "kcf"))


def ablation_rows() -> list[tuple[str, dict[str, Any]]]:
    """``(label, overrides)`` for every combination and appearance, in Table 3's order."""
    return [
        (f"{label} ({app_label})", {**over, "appearance": app})
        for label, over in ABLATION
        for app_label, app in APPEARANCES
    ]
