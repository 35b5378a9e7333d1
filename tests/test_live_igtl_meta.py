"""The quality metadata of a TRANSFORM: PLUS's TransformStatus / TransformValid from the solver
status and the distortion flag (the table of docs/live.md), and the 0-255 distortion level."""

from __future__ import annotations

import numpy as np

from openemt.live._igtl_meta import distortion_level, transform_metadata, transform_status
from openemt.solve import Status


def test_transform_status_table():
    codes = [Status.CONVERGED, Status.CONVERGED, Status.INVALID_INPUT, Status.OUT_OF_VOLUME,
             Status.MAX_ITERATIONS, Status.AMBIGUOUS, Status.NOT_CONVERGED, 99]
    distorted = [False, True, False, False, False, False, False, False]
    assert transform_status(codes, distorted).tolist() == [
        "OK", "INVALID", "MISSING", "OUT_OF_VIEW", "INVALID", "INVALID", "INVALID", "INVALID"]
    meta = transform_metadata(distorted, np.full(8, 1e-6), np.full(8, 1e-5),
                              distortion_threshold=1e-3, status=codes)
    assert meta["TransformValid"] == ["true"] + ["false"] * 7


def test_distortion_level():
    q = np.array([0.0, 1e-5, 5e-4, 1e-3, 1.5e-3, 2e-3, 1.0, 0.0, np.nan])
    r = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.02, np.nan])
    got = distortion_level(q, r, 1e-3, 1e-2)
    assert got.tolist() == [0, 1, 64, 128, 192, 255, 255, 255, 255]   # NaN: the worst
    assert distortion_level([1e-5], [0.005], 1e-3, 1e-2).tolist() == [64]   # the residual
    meta = transform_metadata(np.zeros(3, bool), [0.0, 0.005, np.nan], [0.0, 0.0, 2e-3],
                              distortion_threshold=1e-3)
    assert meta["DistortionLevel"].tolist() == [b"000", b"064", b"255"]
    assert meta["TransformStatus"].tolist() == [b"OK"] * 3
    assert meta["TransformValid"].tolist() == [b"true"] * 3
