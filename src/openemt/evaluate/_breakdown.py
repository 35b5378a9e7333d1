"""Where the held-out error sits: by range, by stage rotation and by sensor fixture, with the
repeat-pose scatter of the data (its noise floor) beside it.

The breakdown splits error magnitudes into groups a researcher can act on: the distance of the
sensor from the source (a far-field or signal-level effect grows with it), the stage's Rz angle
(an error of the rotary axis shows at some angles) and the sensor fixture (a fixture set by
hand). The repeat scatter compares two measurements of the same commanded pose (e.g. an ``md``
row and the ``ld`` row at the same grid point, angle and fixture, recorded minutes apart) solved
with the same model: model errors cancel in the difference, what is left is noise, drift and
the stage's repeatability -- the floor below which no calibration can bring the error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._result import Result
from ._errors import pose_error_magnitudes

__all__ = ["RANGE_EDGES_MM", "ErrorBreakdown", "RepeatScatter", "error_breakdown",
           "repeat_scatter"]

#: Range bins of :func:`error_breakdown` (mm): r < 150, 150-200, 200-250, >= 250.
RANGE_EDGES_MM = (150.0, 200.0, 250.0)


def _range_labels(edges) -> list:
    e = list(edges)
    return ([f"r < {e[0]:g} mm"] + [f"{a:g}-{b:g} mm" for a, b in zip(e[:-1], e[1:])]
            + [f"r >= {e[-1]:g} mm"])


def _group_stats(trans, rot, keys, labels) -> dict:
    out = {}
    for k, label in enumerate(labels):
        m = keys == k
        t, r = trans[m], rot[m]
        ok = np.isfinite(t) & np.isfinite(r)
        out[label] = {"n": int(m.sum()),
                      "trans_rms_mm": float(np.sqrt(np.mean(t[ok] ** 2)) * 1e3) if ok.any()
                      else None,
                      "rot_rms_deg": float(np.rad2deg(np.sqrt(np.mean(r[ok] ** 2)))) if ok.any()
                      else None}
    return out


def _check_rows(trans, rot, n_name, **arrays):
    trans = np.asarray(trans, dtype=np.float64).ravel()
    rot = np.asarray(rot, dtype=np.float64).ravel()
    if trans.shape != rot.shape:
        raise InputError(f"expected `trans` and `rot` of one length, got {trans.size} and "
                         f"{rot.size}")
    for name, a in arrays.items():
        if a is not None and len(a) != trans.size:
            raise InputError(f"expected `{name}` with {trans.size} rows ({n_name}), got {len(a)}")
    return trans, rot


@dataclass(frozen=True)
class ErrorBreakdown(Result):
    """Held-out error RMS per group (:func:`error_breakdown`).

    Attributes
    ----------
    overall : dict
        ``n``, ``trans_rms_mm``, ``rot_rms_deg`` of every row.
    by_range, by_rz, by_sensor_fixture : dict of str -> dict
        The same statistics per range bin (label like ``"200-250 mm"``), per stage Rz angle
        (label like ``"-90 deg"``) and per sensor-fixture code; empty groups have ``n = 0`` and
        None statistics (range bins) or are left out (angles, fixtures). Non-finite errors
        (failed solutions) are counted in ``n`` but not in the RMS.
    """

    overall: dict
    by_range: dict
    by_rz: dict
    by_sensor_fixture: dict

    def rows(self) -> list:
        """Flat table rows ``{"group", "n", "trans_rms_mm", "rot_rms_deg"}`` for reports."""
        out = [{"group": "all", **self.overall}]
        for kind, d in (("range", self.by_range), ("Rz", self.by_rz),
                        ("sensor fixture", self.by_sensor_fixture)):
            out += [{"group": f"{kind} {label}", **s} for label, s in d.items()]
        return out


def error_breakdown(trans, rot, positions, *, stage_rz=None, sensor_fixture=None,
                    range_edges_mm=RANGE_EDGES_MM) -> ErrorBreakdown:
    """RMS errors by range, stage rotation and sensor fixture.

    Parameters
    ----------
    trans, rot : array_like, shape (N,)
        Error magnitudes (m, rad), e.g. of :func:`pose_error_magnitudes`.
    positions : array_like, shape (N, 3)
        Reference sensor positions in the source frame (m); the range is their norm.
    stage_rz : array_like, shape (N,), optional
        Stage Rz angle of each row (rad); grouped to the nearest 0.1 degree.
    sensor_fixture : array_like of str, shape (N,), optional
        Sensor-fixture code of each row.
    range_edges_mm : sequence of float
        Bin edges of the range (mm, increasing).

    Examples
    --------
    >>> import numpy as np
    >>> b = error_breakdown([1e-4, 3e-4], [0.0, 0.0], [[0.17, 0, 0], [0.3, 0, 0]],
    ...                     stage_rz=np.deg2rad([0.0, 90.0]), sensor_fixture=["A", "A"])
    >>> round(b.by_range["r >= 250 mm"]["trans_rms_mm"], 3), b.by_rz["90 deg"]["n"]
    (0.3, 1)
    """
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise InputError(f"expected `positions` of shape (N, 3), got {pos.shape}")
    trans, rot = _check_rows(trans, rot, "one per error", positions=pos, stage_rz=stage_rz,
                             sensor_fixture=sensor_fixture)
    edges = np.asarray(range_edges_mm, dtype=np.float64)
    if edges.ndim != 1 or edges.size == 0 or np.any(np.diff(edges) <= 0):
        raise InputError(f"expected increasing `range_edges_mm`, got {list(range_edges_mm)}")
    r_mm = np.linalg.norm(pos, axis=1) * 1e3
    overall = _group_stats(trans, rot, np.zeros(trans.size, dtype=int), ["all"])["all"]
    by_range = _group_stats(trans, rot, np.searchsorted(edges, r_mm, side="right"),
                            _range_labels(edges))
    by_rz = {}
    if stage_rz is not None:
        deg = np.round(np.rad2deg(np.asarray(stage_rz, dtype=np.float64)), 1) + 0.0
        values = np.unique(deg[np.isfinite(deg)])
        keys = np.searchsorted(values, deg)
        by_rz = _group_stats(trans, rot, np.where(np.isfinite(deg), keys, -1),
                             [f"{v:g} deg" for v in values])
    by_se = {}
    if sensor_fixture is not None:
        codes = np.asarray(sensor_fixture).astype(str)
        values, keys = np.unique(codes, return_inverse=True)
        by_se = _group_stats(trans, rot, keys.ravel(), [str(v) for v in values])
    return ErrorBreakdown(overall=overall, by_range=by_range, by_rz=by_rz,
                          by_sensor_fixture=by_se)


@dataclass(frozen=True)
class RepeatScatter(Result):
    """Scatter of repeated measurements of the same pose (:func:`repeat_scatter`).

    Attributes
    ----------
    n_pairs : int
        Pairs with finite solutions.
    trans_rms_mm, rot_rms_deg : float or None
        Per-measurement scatter ``sqrt(mean(|d|^2) / 2)`` of the pair differences ``d``: the
        RMS error a perfect model would still show.
    by_range : dict
        The same per range bin of :data:`RANGE_EDGES_MM`.
    """

    n_pairs: int
    trans_rms_mm: float | None
    rot_rms_deg: float | None
    by_range: dict


def repeat_scatter(poses_a, poses_b, *, range_edges_mm=RANGE_EDGES_MM) -> RepeatScatter:
    """Noise floor from pairs of poses solved from two measurements of one commanded pose.

    ``poses_a[k]`` and ``poses_b[k]`` (each ``(N, 4, 4)``, source frame) are the same rig pose
    measured twice. The per-measurement scatter is ``sqrt(mean(|d|^2) / 2)`` (a difference of
    two independent errors has twice their variance); the range is that of ``poses_a``.

    Examples
    --------
    >>> import numpy as np
    >>> from openemt.geometry import pose_from_vector
    >>> a = pose_from_vector(np.array([[0.2, 0, 0, 0, 0, 0], [0.3, 0, 0, 0, 0, 0]]))
    >>> b = pose_from_vector(np.array([[0.2002, 0, 0, 0, 0, 0], [0.3, 0.0002, 0, 0, 0, 0]]))
    >>> s = repeat_scatter(a, b)
    >>> s.n_pairs, round(s.trans_rms_mm, 4)
    (2, 0.1414)
    """
    A = np.asarray(poses_a, dtype=np.float64)
    B = np.asarray(poses_b, dtype=np.float64)
    if A.shape != B.shape:
        raise InputError(f"expected two pose arrays of one shape, got {A.shape} and {B.shape}")
    t, r = pose_error_magnitudes(A, B) if len(A) else (np.zeros(0), np.zeros(0))
    half = 1.0 / np.sqrt(2.0)
    b = error_breakdown(t * half, r * half, A[:, :3, 3] if len(A) else np.zeros((0, 3)),
                        range_edges_mm=range_edges_mm)
    ok = np.isfinite(t) & np.isfinite(r)
    return RepeatScatter(n_pairs=int(ok.sum()), trans_rms_mm=b.overall["trans_rms_mm"],
                         rot_rms_deg=b.overall["rot_rms_deg"], by_range=b.by_range)
