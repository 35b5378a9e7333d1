"""The quality of each sent pose as OpenIGTLink version-2 metadata of its TRANSFORM, in the keys
PLUS reads (``TransformStatus``, ``TransformValid``) and openemt's own (``RelativeResidual``,
``QuadratureRatio``, ``DistortionLevel``); the table is in docs/live.md."""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from .._compile_notice import warm_up_with
from ..solve import Status
from ..solve._validity import MAX_RELATIVE_RESIDUAL

__all__ = ["BAND_THRESHOLD", "TRANSFORM_STATUS", "WITNESS_THRESHOLD_M", "distortion_level", "transform_metadata", "transform_status"]

#: PLUS's tool status (``TransformStatus``) of each solver status of a sample.
TRANSFORM_STATUS = {Status.CONVERGED: "OK", Status.INVALID_INPUT: "MISSING",
                    Status.OUT_OF_VOLUME: "OUT_OF_VIEW", Status.MAX_ITERATIONS: "INVALID",
                    Status.AMBIGUOUS: "INVALID", Status.NOT_CONVERGED: "INVALID"}

# "000".."255": a fixed width, so a block's values have one length (packed as arrays)
_LEVELS = np.array([b"%03d" % i for i in range(256)], dtype="S3")


def transform_status(status, distorted) -> np.ndarray:
    """``TransformStatus`` per sample: the solver status through :data:`TRANSFORM_STATUS`,
    and ``INVALID`` for a converged pose flagged distorted."""
    st = np.asarray(status, dtype=np.int64)
    out = np.full(st.shape, "INVALID", dtype="U11")
    for code, name in TRANSFORM_STATUS.items():
        out[st == int(code)] = name
    out[(st == int(Status.CONVERGED)) & np.asarray(distorted, bool)] = "INVALID"
    return out


#: Thresholds (the level's 128) of the two optional indicators of :func:`distortion_level`:
#: the relative disagreement between two carrier bands' in-phase couplings, and the position
#: error of a fixed witness sensor at its known pose (m).
BAND_THRESHOLD = 0.01
WITNESS_THRESHOLD_M = 1e-3


def distortion_level(quadrature, relative_residual, distortion_threshold: float,
                     residual_threshold: float, *, band=None, witness_m=None,
                     band_threshold: float = BAND_THRESHOLD,
                     witness_threshold_m: float = WITNESS_THRESHOLD_M) -> np.ndarray:
    """A 0-255 distortion level per sample (as Polhemus VIPER reports one per sensor), from
    what the sample itself shows: ``128 * max(q / q_max, r / r_max, b / b_max, w / w_max)``
    rounded (half up) and clipped to 255, with q the quadrature ratio against the distortion
    threshold, r the solve's relative residual against the solver's validity threshold and,
    where the tracker has them, b the relative disagreement between two carrier bands
    (``||Re C_fast - Re C_slow|| / ||C||``) against :data:`BAND_THRESHOLD` and w the position
    error of a fixed witness sensor at its known pose against :data:`WITNESS_THRESHOLD_M` (a
    NaN residual, band or witness figure counts as 0, a NaN quadrature ratio as the worst).
    0: clean; 128: at a threshold (the sample is flagged distorted or invalid from there);
    255: twice a threshold or more."""
    q = np.ascontiguousarray(quadrature, dtype=np.float64)
    r = np.ascontiguousarray(relative_residual, dtype=np.float64)
    rs = 128.0 / float(residual_threshold)
    if band is not None or witness_m is not None:
        r = r * rs
        for v, thr in ((band, band_threshold), (witness_m, witness_threshold_m)):
            if v is not None:
                r = np.fmax(r, np.broadcast_to(np.asarray(v, np.float64), r.shape)
                            * (128.0 / float(thr)))
        r, rs = np.ascontiguousarray(r), 1.0
    out = np.empty(q.shape[0], np.uint8)
    _levels(q, r, 128.0 / float(distortion_threshold), rs, out)
    return out


@njit(cache=True)
def _levels(q, r, qs, rs, out):
    """The level of each sample in one compiled loop (this runs for every block sent)."""
    for i in range(q.shape[0]):
        x = q[i] * qs
        y = r[i] * rs
        if y > x:                      # a NaN residual never wins: it counts as 0
            x = y
        if not x < 255.0:              # also a NaN quadrature ratio: the worst
            out[i] = 255
        else:
            out[i] = np.uint8(x + 0.5) if x > 0.0 else 0


@functools.lru_cache(maxsize=64)
def _all_ok(n: int) -> tuple:
    """``TransformStatus`` and ``TransformValid`` of n good poses, as read-only bytes arrays
    (no encoding per value when packed)."""
    ok, true = np.full(n, b"OK", "S2"), np.full(n, b"true", "S4")
    ok.flags.writeable = true.flags.writeable = False
    return ok, true


def transform_metadata(distorted, relative_residual, quadrature, *,
                       distortion_threshold: float,
                       residual_threshold: float = MAX_RELATIVE_RESIDUAL,
                       status=None, level=None) -> dict:
    """The metadata of N TRANSFORMs (key -> N values, as :meth:`IgtlServer.send_poses` takes
    them). ``status``: the solver status per sample (default: all converged, as the sent
    poses are); ``distorted``: the quadrature flag per sample; ``residual_threshold``: the
    solver's validity threshold on the relative residual (default the solver's, 1 %);
    ``level``: the samples' distortion levels where the caller has them (the pipeline's,
    witnesses included), else computed here from the quadrature and residual."""
    dist = np.asarray(distorted, dtype=bool)
    n = dist.shape[0]
    if status is None and not dist.any():       # the usual block: every pose good, as bytes
        ts, valid = _all_ok(n)
    else:
        names = transform_status(np.zeros(n, np.int64) if status is None else status, dist)
        ts = names.tolist()
        valid = np.where(names == "OK", "true", "false").tolist()
    if level is None:
        level = distortion_level(quadrature, relative_residual, distortion_threshold,
                                 residual_threshold)
    return {"TransformStatus": ts, "TransformValid": valid,
            "RelativeResidual": np.asarray(relative_residual, dtype=np.float64),
            "QuadratureRatio": np.asarray(quadrature, dtype=np.float64),
            "DistortionLevel": _LEVELS[level]}


warm_up_with("openemt.live._igtl_meta:_levels",
             lambda: distortion_level(np.array([0.1]), np.array([0.1]), 0.5, 0.5))
