"""Standard accuracy assessment of a tracker on a precisely machined grid.

The protocol of Hummel et al. 2005 ("Design and application of an assessment protocol for
electromagnetic tracking systems", Med. Phys. 32(7):2371-2379) and the point-to-point and
repeatability measures of ASTM F2554: a sensor is placed in the holes of a grid of known
geometry (50 mm pitch in Hummel's board), several samples are recorded in each, and

* the measured points are fitted rigidly to the nominal grid (:func:`register_points`): the
  residuals (RMS, mean, max, per point) are the position errors the frame cannot explain;
* every distance between two measured points is compared with the nominal distance: all
  pairs, and the classes of nominal distance 50, 150 and 300 mm (within ``class_tolerance``);
  the distance errors need no common frame at all;
* the samples repeated at one point give the jitter (RMS and max distance from their mean);
* when the tracker gives orientations (the sensor keeps one orientation over the grid), their
  angles from the mean orientation are the rotation errors.

Correspondence: ``"order"`` pairs the i-th measured point (after averaging repeats) with the
i-th nominal one; ``"nearest"`` finds the pairing by nearest neighbours after a first rigid fit
(an iterative closest point with one-to-one assignment, started from the identity and from the
principal-axes alignments, keeping the start that fits best), so measured points may come in
any order and cover only part of the grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import ClassVar

import numpy as np

from .._errors import InputError
from .._result import Result
from ..geometry import check_points
from ._register import register_points

__all__ = ["DISTANCE_CLASSES_MM", "GridAssessment", "assess_grid", "regular_grid"]

#: Nominal-distance classes (mm) of Hummel et al. 2005.
DISTANCE_CLASSES_MM = (50.0, 150.0, 300.0)


def regular_grid(pitch, shape) -> np.ndarray:
    """Nodes of a regular grid, (prod(shape), 3), x fastest, starting at the origin.

    ``pitch`` (m) is one number or one per axis; ``shape`` the node count per axis (1 to 3
    numbers, the missing ones 1).
    """
    shape = tuple(int(s) for s in np.atleast_1d(shape))
    if not 1 <= len(shape) <= 3 or any(s < 1 for s in shape) or int(np.prod(shape)) > 100_000:
        raise InputError(f"expected 1 to 3 node counts >= 1 (at most 100000 nodes), got {shape}")
    shape = shape + (1,) * (3 - len(shape))
    pitch = np.broadcast_to(np.asarray(pitch, dtype=np.float64), (3,))
    if not np.all(np.isfinite(pitch)) or np.any(pitch <= 0):
        raise InputError(f"expected a positive grid pitch, got {pitch.tolist()}")
    idx = np.array([(i, j, k) for k, j, i in product(range(shape[2]), range(shape[1]),
                                                     range(shape[0]))], dtype=np.float64)
    return idx * pitch


def _pca_starts(meas, nom):
    """Rigid starts (R, t) aligning the principal axes of ``meas`` with those of ``nom``."""
    cm, cn = meas.mean(axis=0), nom.mean(axis=0)
    Vm = np.linalg.svd(meas - cm, full_matrices=False)[2].T
    Vn = np.linalg.svd(nom - cn, full_matrices=False)[2].T
    out = []
    for signs in product((1.0, -1.0), repeat=3):
        R = Vn @ np.diag(signs) @ Vm.T
        if np.linalg.det(R) > 0:
            out.append((R, cn - R @ cm))
    return out


def _match_nearest(meas, nom, max_iter: int = 50):
    """Index of the nominal point of every measured point (one-to-one ICP)."""
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    starts = [(np.eye(3), np.zeros(3)), (np.eye(3), nom.mean(0) - meas.mean(0))]
    starts += _pca_starts(meas, nom)
    best, best_rms = None, np.inf
    for R, t in starts:
        cols = None
        for _ in range(max_iter):
            cost = cdist(meas @ R.T + t, nom, "sqeuclidean")
            _, new = linear_sum_assignment(cost)
            if cols is not None and np.array_equal(new, cols):
                break
            cols = new
            reg = register_points(nom[cols], meas)
            R, t = reg.transform[:3, :3], reg.transform[:3, 3]
        rms = float(np.sqrt(np.mean(np.sum((meas @ R.T + t - nom[cols]) ** 2, axis=1))))
        if rms < best_rms - 1e-12:
            best, best_rms = cols, rms
    return best


@dataclass(frozen=True, eq=False)
class GridAssessment(Result):
    """Result of :func:`assess_grid` (SI units inside; ``to_dict()`` gives mm and deg).

    Attributes
    ----------
    match : str
    nominal_index : ndarray of int, shape (n,)
        Nominal point of every measured point.
    measured, nominal : ndarray, shape (n, 3)
        Measured points (repeats averaged) and their nominal partners (m).
    residuals : ndarray, shape (n, 3)
        Rigidly fitted measured point minus nominal point (m, nominal frame).
    transform : ndarray, shape (4, 4)
        The rigid fit, measured frame -> nominal frame.
    pair_index : ndarray of int, shape (P, 2)
        The point pairs of the distance errors.
    nominal_distance, distance_error : ndarray, shape (P,)
        Nominal distance and measured minus nominal distance per pair (m).
    jitter : dict or None
        :meth:`openemt.io.StaticAverage.summary` of the repeated samples (mm, deg).
    rotation_errors : ndarray, shape (n,) or None
        Angle of each point's orientation from the mean orientation (rad).
    n_rows, n_nonfinite : int
        Measured rows read, and rows left out as not finite.
    class_tolerance : float
        Half-width (m) of the distance classes.
    """

    match: str
    nominal_index: np.ndarray
    measured: np.ndarray
    nominal: np.ndarray
    residuals: np.ndarray
    transform: np.ndarray
    pair_index: np.ndarray
    nominal_distance: np.ndarray
    distance_error: np.ndarray
    jitter: dict | None
    rotation_errors: np.ndarray | None
    n_rows: int
    n_nonfinite: int
    class_tolerance: float
    _not_in_dict: ClassVar[tuple] = ()

    @property
    def n(self) -> int:
        return len(self.measured)

    @property
    def residual_distances(self) -> np.ndarray:
        return np.linalg.norm(self.residuals, axis=1)

    def distance_classes(self) -> dict:
        """Distance-error statistics (mm) per nominal-distance class of Hummel et al. 2005."""
        out = {}
        for c in DISTANCE_CLASSES_MM:
            sel = np.abs(self.nominal_distance - 1e-3 * c) <= self.class_tolerance
            out[f"{c:g}"] = _distance_stats(self.distance_error[sel])
        return out

    def _items(self) -> dict:
        d = self.residual_distances
        out = {"n": self.n, "n_rows": self.n_rows, "n_nonfinite": self.n_nonfinite,
               "match": self.match,
               "rigid_rms_mm": 1e3 * float(np.sqrt(np.mean(d ** 2))),
               "rigid_mean_mm": 1e3 * float(np.mean(d)),
               "rigid_max_mm": 1e3 * float(np.max(d))}
        s = _distance_stats(self.distance_error)
        out.update({f"distance_error_{k}": v for k, v in s.items() if k != "n"})
        out["n_distances"] = s["n"]
        out["distance_classes"] = self.distance_classes()
        out["distance_class_tolerance_mm"] = 1e3 * self.class_tolerance
        out["jitter"] = self.jitter
        if self.rotation_errors is not None:
            r = np.rad2deg(self.rotation_errors)
            out["rotation_error_rms_deg"] = float(np.sqrt(np.mean(r ** 2)))
            out["rotation_error_max_deg"] = float(np.max(r))
        out["transform"] = self.transform
        out["points"] = {"nominal_index": self.nominal_index,
                         "residual_mm": 1e3 * self.residuals,
                         "residual_distance_mm": 1e3 * d}
        return out


def _distance_stats(e) -> dict:
    e = 1e3 * np.asarray(e, dtype=np.float64)
    if len(e) == 0:
        nan = float("nan")
        return {"n": 0, "mean_mm": nan, "rms_mm": nan, "bias_mm": nan, "std_mm": nan,
                "max_mm": nan}
    return {"n": len(e), "mean_mm": float(np.mean(np.abs(e))),
            "rms_mm": float(np.sqrt(np.mean(e ** 2))), "bias_mm": float(np.mean(e)),
            "std_mm": float(np.std(e, ddof=1)) if len(e) > 1 else 0.0,
            "max_mm": float(np.max(np.abs(e)))}


def assess_grid(measured, nominal, *, match: str = "order", groups=None,
                has_orientation: bool | None = None,
                class_tolerance: float = 0.5e-3) -> GridAssessment:
    """Assess measured grid points against their nominal positions.

    Parameters
    ----------
    measured : array_like, shape (N, 3) or (N, 4, 4)
        Measured positions or poses (m); non-finite rows are left out and counted.
    nominal : array_like, shape (M, 3)
        Nominal grid positions (m).
    match : {"order", "nearest"}
        Correspondence, see the module docstring.
    groups : array_like, shape (N,), optional
        Label of the grid point each sample belongs to (repeated samples): samples are
        averaged per label (in order of first appearance) and their jitter reported.
    has_orientation : bool, optional
        Whether poses carry orientations (default: True for poses, False for points).
    class_tolerance : float
        Half-width (m) of the nominal-distance classes.

    Returns
    -------
    GridAssessment
    """
    from ..io import average_static

    if match not in ("order", "nearest"):
        raise InputError(f"expected match 'order' or 'nearest', got {match!r}")
    a = np.asarray(measured, dtype=np.float64)
    if a.ndim == 3 and a.shape[1:] == (4, 4):
        P = a.copy()
        rot = True if has_orientation is None else bool(has_orientation)
    else:
        pts = check_points(a, "measured")
        if pts.ndim != 2:
            raise InputError(f"expected measured points (N, 3) or poses (N, 4, 4), got "
                             f"{a.shape}")
        P = np.tile(np.eye(4), (len(pts), 1, 1))
        P[:, :3, 3] = pts
        rot = False
    nom = check_points(nominal, "nominal")
    if nom.ndim != 2 or len(nom) < 3 or not np.all(np.isfinite(nom)):
        raise InputError(f"expected at least 3 finite nominal points (M, 3), got shape "
                         f"{nom.shape}")
    n_rows = len(P)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    g = None if groups is None else np.asarray(groups)
    if g is not None and g.shape != (n_rows,):
        raise InputError(f"expected groups of shape ({n_rows},), got {g.shape}")
    P = P[ok]
    jitter = None
    if g is not None and len(P):
        avg = average_static(P, g[ok])
        if np.any(avg.counts > 1):
            jitter = avg.summary()
            if not rot:
                jitter = {k: v for k, v in jitter.items() if "_rot_" not in k}
        P = avg.poses
    if len(P) < 3:
        raise InputError(f"expected at least 3 finite measured points, got {len(P)} (of "
                         f"{n_rows} rows)")
    meas = P[:, :3, 3]
    if match == "order":
        if len(meas) != len(nom):
            raise InputError(f"expected as many measured points (after averaging repeats) as "
                             f"nominal ones for match 'order', got {len(meas)} and {len(nom)}: "
                             f"check the files or use match 'nearest'")
        idx = np.arange(len(nom))
    else:
        if len(meas) > len(nom):
            raise InputError(f"expected at most as many measured points as nominal ones for "
                             f"match 'nearest', got {len(meas)} and {len(nom)}")
        idx = _match_nearest(meas, nom)
    nm = nom[idx]
    reg = register_points(nm, meas)
    iu, ju = np.triu_indices(len(meas), k=1)
    dn = np.linalg.norm(nm[iu] - nm[ju], axis=1)
    dm = np.linalg.norm(meas[iu] - meas[ju], axis=1)
    rot_err = None
    if rot:
        from scipy.spatial.transform import Rotation

        r = Rotation.from_matrix(P[:, :3, :3])
        rot_err = (r * r.mean().inv()).magnitude()
    return GridAssessment(match=match, nominal_index=idx, measured=meas, nominal=nm,
                          residuals=reg.residuals, transform=reg.transform,
                          pair_index=np.stack([iu, ju], axis=1), nominal_distance=dn,
                          distance_error=dm - dn, jitter=jitter, rotation_errors=rot_err,
                          n_rows=n_rows, n_nonfinite=int((~ok).sum()),
                          class_tolerance=float(class_tolerance))
