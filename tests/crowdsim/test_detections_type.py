"""``crowdsim.detections.Detections``: exact results of indexing, masking, merging and
``from_points`` on tiny hand-built arrays, the empty frame, and bad shapes named by field."""

from __future__ import annotations

import numpy as np
import pytest

from crowdsim.detections import Detections


def _three() -> Detections:
    return Detections(
        xyxy=np.array([[0.0, 0, 2, 2], [10, 10, 14, 12], [5, 1, 7, 5]]),
        confidence=np.array([0.9, 0.2, 0.6]),
        gt_id=np.array([7, -1, 3]),
    )


def test_fields_dtypes_and_default_gt_id():
    d = Detections([[0, 0, 2, 4]], [1])  # lists of ints are converted
    assert d.xyxy.dtype == np.float64 and d.confidence.dtype == np.float64
    assert d.gt_id.dtype == np.int64 and d.gt_id.tolist() == [-1]
    assert len(d) == 1 and d.centers.tolist() == [[1.0, 2.0]] and d.points.tolist() == [[1, 2]]
    assert _three().centers.tolist() == [[1, 1], [12, 11], [6, 3]]


def test_int_slice_mask_and_index_array():
    d = _three()
    one = d[1]
    assert isinstance(one, Detections) and len(one) == 1
    assert one.xyxy.tolist() == [[10, 10, 14, 12]] and one.gt_id.tolist() == [-1]
    assert d[-1].gt_id.tolist() == [3] and d[np.int64(0)].confidence.tolist() == [0.9]
    assert d[1:].gt_id.tolist() == [-1, 3] and d[::2].confidence.tolist() == [0.9, 0.6]
    strong = d[d.confidence > 0.5]
    assert strong.gt_id.tolist() == [7, 3]
    assert strong.xyxy.tolist() == [[0, 0, 2, 2], [5, 1, 7, 5]]
    picked = d[np.array([2, 0, 2])]  # every field follows the same index, repeats included
    assert picked.gt_id.tolist() == [3, 7, 3] and picked.confidence.tolist() == [0.6, 0.9, 0.6]
    assert picked.xyxy[:, 0].tolist() == [5, 0, 5]
    none = d[np.zeros(3, bool)]
    assert len(none) == 0 and none.xyxy.shape == (0, 4) and none.gt_id.dtype == np.int64
    assert len(d[[]]) == 0
    with pytest.raises(IndexError, match="boolean mask of shape \\(2,\\) for 3 detections"):
        d[np.array([True, False])]
    with pytest.raises(IndexError, match="1-D integer index"):
        d[np.array([0.5])]
    with pytest.raises(IndexError):
        d[3]
    # a new object: the original is unchanged
    assert len(d) == 3 and d.gt_id.tolist() == [7, -1, 3]


def test_empty_and_merge():
    e = Detections.empty()
    assert len(e) == 0 and e.xyxy.shape == (0, 4) and e.confidence.shape == (0,)
    assert e.gt_id.shape == (0,) and e.centers.shape == (0, 2)
    d = _three()
    m = Detections.merge([e, d[2], e, d[:2]])
    assert m.gt_id.tolist() == [3, 7, -1] and m.confidence.tolist() == [0.6, 0.9, 0.2]
    assert m.xyxy.tolist() == [[5, 1, 7, 5], [0, 0, 2, 2], [10, 10, 14, 12]]
    assert len(Detections.merge([])) == 0 and len(Detections.merge([e, e])) == 0
    assert Detections.merge([e, d]).gt_id.dtype == np.int64
    with pytest.raises(ValueError, match="takes Detections, got tuple at position 1"):
        Detections.merge([d, (d.xyxy, d.confidence)])


def test_from_points_boxes_and_clipping():
    pts = [[10.0, 10.0], [1.0, 30.0], [63.0, 0.5]]
    free = Detections.from_points(pts, [0.9, 0.5, 0.3], box_px=4.0)
    assert free.xyxy.tolist() == [[8, 8, 12, 12], [-1, 28, 3, 32], [61, -1.5, 65, 2.5]]
    assert free.gt_id.tolist() == [-1, -1, -1]
    clipped = Detections.from_points(pts, [0.9, 0.5, 0.3], 4.0, width=64, height=31)
    assert clipped.xyxy.tolist() == [[8, 8, 12, 12], [0, 28, 3, 31], [61, 0, 64, 2.5]]
    only_x = Detections.from_points(pts, [0.9, 0.5, 0.3], 4.0, width=64)
    assert only_x.xyxy.tolist() == [[8, 8, 12, 12], [0, 28, 3, 32], [61, -1.5, 64, 2.5]]
    ids = Detections.from_points(pts, [0.9, 0.5, 0.3], 4.0, gt_id=[4, 5, 6])
    assert ids.gt_id.tolist() == [4, 5, 6] and ids.centers.tolist() == pts
    none = Detections.from_points(np.zeros((0, 2)), [], 4.0, 10, 10)
    assert len(none) == 0 and none.xyxy.shape == (0, 4)


@pytest.mark.parametrize(
    "kw, needle",
    [
        (dict(xyxy=np.zeros((2, 3)), confidence=np.zeros(2)), r"xyxy must have shape \(m, 4\)"),
        (dict(xyxy=np.zeros(4), confidence=np.zeros(1)), r"xyxy must have shape \(m, 4\)"),
        (dict(xyxy=np.zeros((2, 4)), confidence=np.zeros(3)), r"confidence must have shape \(2,\)"),
        (
            dict(xyxy=np.zeros((2, 4)), confidence=np.zeros(2), gt_id=np.zeros(1, int)),
            r"gt_id must have shape \(2,\)",
        ),
        (
            dict(xyxy=np.zeros((1, 4)), confidence=np.zeros(1), gt_id=np.array([1.5])),
            "gt_id must hold integers",
        ),
    ],
)
def test_bad_shapes_name_the_field(kw, needle):
    with pytest.raises(ValueError, match=f"Detections.{needle}"):
        Detections(**kw)


def test_from_points_bad_input():
    with pytest.raises(ValueError, match=r"points must have shape \(m, 2\), got \(2, 3\)"):
        Detections.from_points(np.zeros((2, 3)), np.zeros(2), 4.0)
    with pytest.raises(ValueError, match=r"Detections.confidence must have shape \(2,\)"):
        Detections.from_points(np.zeros((2, 2)), np.zeros(1), 4.0)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="Detections.from_points.box_px"):
            Detections.from_points(np.zeros((1, 2)), [1.0], bad)
    with pytest.raises(ValueError, match="Detections.from_points.height"):
        Detections.from_points(np.zeros((1, 2)), [1.0], 4.0, width=10, height=0)
