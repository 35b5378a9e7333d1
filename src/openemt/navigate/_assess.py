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
(an iterative closest point on a k-d tree, ``O(n log m)`` per iteration, started from the
identity and the principal-axes alignments, and where these axes are not unique or fail from
the 24 rotations of a cube about the centroids, keeping the start that fits best with every
nominal point matched at most once), so measured points may come in any order and cover only
part of the grid.

Work is bounded: at most ``MAX_ASSESS_POINTS`` points (after averaging repeats); the
statistics of the ``n (n - 1) / 2`` distances are accumulated in one compiled pass (memory
``O(1)``), and the result keeps at most ``MAX_STORED_PAIRS`` of the pairs (evenly spaced) for
the figures.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product
from typing import ClassVar

import numpy as np

from .._errors import InputError
from .._result import Result
from ..geometry import check_points, pose_from_rt
from ._register import register_points

__all__ = ["DISTANCE_CLASSES_MM", "MAX_ASSESS_POINTS", "MAX_STORED_PAIRS", "GridAssessment",
           "assess_grid", "regular_grid"]

#: Nominal-distance classes (mm) of Hummel et al. 2005.
DISTANCE_CLASSES_MM = (50.0, 150.0, 300.0)
#: Most measured points (after averaging repeats) an assessment takes (2e8 distances).
MAX_ASSESS_POINTS = 20_000
#: Most point pairs kept in the result (for the figures); the statistics use every pair.
MAX_STORED_PAIRS = 200_000


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


def _icp(tree, meas, nom, R, t, max_iter):
    """Nearest-neighbour ICP from ``(R, t)``: (nominal index per measured point, RMS), or
    None when the final pairing uses a nominal point twice."""
    from ._register import rigid_fit

    cols = None
    for _ in range(max_iter):
        new = tree.query(meas @ R.T + t)[1]
        if cols is not None and np.array_equal(new, cols):
            break
        cols = new
        Rb, tb, _ = rigid_fit(nom[cols][None], meas[None])
        R, t = Rb[0], tb[0]
    if len(np.unique(cols)) < len(cols):
        return None
    return cols, float(np.sqrt(np.mean(np.sum((meas @ R.T + t - nom[cols]) ** 2, axis=1))))


def _match_nearest(meas, nom, max_iter: int = 50):
    """Index of the nominal point of every measured point (ICP on a k-d tree from several
    starts; a start whose final pairing uses a nominal point twice is not taken)."""
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    tree = cKDTree(nom)
    cm, cn = meas.mean(axis=0), nom.mean(axis=0)
    found = [r for R, t in [(np.eye(3), np.zeros(3))] + _pca_starts(meas, nom)
             if (r := _icp(tree, meas, nom, R, t, max_iter)) is not None]
    sv = [np.linalg.svd(x - x.mean(axis=0), compute_uv=False) for x in (meas, nom)]
    if not found or any(np.min(v[1:] / np.maximum(v[:-1], 1e-300)) > 0.9 for v in sv):
        # principal axes not unique (a cube, a square grid): the 24 rotations of a cube about
        # the centroids give a start near every symmetric pairing
        found += [r for R in Rotation.create_group("O").as_matrix()
                  if (r := _icp(tree, meas, nom, R, cn - R @ cm, max_iter)) is not None]
    if not found:
        raise InputError("expected measured points that match distinct nominal points, got "
                         "several nearest to one nominal point from every start: check the "
                         "nominal grid and its units, or use match 'order'")
    return min(found, key=lambda r: r[1])[0]


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
        Nominal distance and measured minus nominal distance per pair (m); at most
        ``MAX_STORED_PAIRS`` pairs, evenly spaced over all of them.
    distance_stats : dict
        Statistics (mm) of the errors of every pair: ``"all"`` and one per distance class.
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
    distance_stats: dict
    _not_in_dict: ClassVar[tuple] = ()

    @property
    def n(self) -> int:
        return len(self.measured)

    @property
    def residual_distances(self) -> np.ndarray:
        return np.linalg.norm(self.residuals, axis=1)

    def distance_classes(self) -> dict:
        """Distance-error statistics (mm) per nominal-distance class of Hummel et al. 2005."""
        return {k: v for k, v in self.distance_stats.items() if k != "all"}

    def _items(self) -> dict:
        d = self.residual_distances
        out = {"n": self.n, "n_rows": self.n_rows, "n_nonfinite": self.n_nonfinite,
               "match": self.match,
               "rigid_rms_mm": 1e3 * float(np.sqrt(np.mean(d ** 2))),
               "rigid_mean_mm": 1e3 * float(np.mean(d)),
               "rigid_max_mm": 1e3 * float(np.max(d))}
        s = self.distance_stats["all"]
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


def _stats(acc) -> dict:
    """Statistics (mm) from the sums ``[n, sum |e|, sum e, sum e^2, max |e|]`` (m)."""
    n, sa, se, s2, mx = acc
    if n == 0:
        nan = float("nan")
        return {"n": 0, "mean_mm": nan, "rms_mm": nan, "bias_mm": nan, "std_mm": nan,
                "max_mm": nan}
    mean = se / n
    var = max(s2 - n * mean ** 2, 0.0) / (n - 1) if n > 1 else 0.0
    return {"n": int(n), "mean_mm": 1e3 * sa / n, "rms_mm": 1e3 * float(np.sqrt(s2 / n)),
            "bias_mm": 1e3 * mean, "std_mm": 1e3 * float(np.sqrt(var)), "max_mm": 1e3 * mx}


def _pair_sums_py(meas, nm, classes, tol, acc):
    """Sums ``[n, sum |e|, sum e, sum e^2, max |e|]`` of the distance errors of every pair
    into ``acc`` (row 0: all pairs, then one row per class); compiled by :func:`_pair_sums`."""
    n = meas.shape[0]
    for i in range(n - 1):
        for j in range(i + 1, n):
            dm = 0.0
            dn = 0.0
            for a in range(3):
                u = meas[i, a] - meas[j, a]
                v = nm[i, a] - nm[j, a]
                dm += u * u
                dn += v * v
            dn = np.sqrt(dn)
            e = np.sqrt(dm) - dn
            ae = abs(e)
            for c in range(classes.shape[0] + 1):
                if c == 0 or abs(dn - classes[c - 1]) <= tol:
                    acc[c, 0] += 1.0
                    acc[c, 1] += ae
                    acc[c, 2] += e
                    acc[c, 3] += e * e
                    if ae > acc[c, 4]:
                        acc[c, 4] = ae


_KERNEL = []


def _pair_sums(meas, nm, classes, tolerance):
    """The sums of :func:`_pair_sums_py` in one compiled pass (numba, cached on disk)."""
    if not _KERNEL:
        from numba import njit

        _KERNEL.append(njit(cache=True)(_pair_sums_py))
    acc = np.zeros((len(classes) + 1, 5))
    _KERNEL[0](np.ascontiguousarray(meas, dtype=np.float64),
               np.ascontiguousarray(nm, dtype=np.float64), classes, float(tolerance), acc)
    return acc


def _pair_distances(meas, nm, tolerance):
    """Statistics of the distance errors of every pair (a compiled pass, memory O(1)) and at
    most ``MAX_STORED_PAIRS`` pairs (evenly spaced in row-major order) with their distances."""
    n = len(meas)
    total = n * (n - 1) // 2
    classes = 1e-3 * np.array(DISTANCE_CLASSES_MM)
    acc = _pair_sums(meas, nm, classes, tolerance)
    k = np.arange(0, total, max(1, -(-total // MAX_STORED_PAIRS)), dtype=np.int64)
    # row i of the upper triangle starts at i n - i (i + 1) / 2
    starts = np.arange(n, dtype=np.int64) * n - np.arange(n, dtype=np.int64) * np.arange(
        1, n + 1, dtype=np.int64) // 2
    i = np.searchsorted(starts, k, side="right") - 1
    j = k - starts[i] + i + 1
    dn = np.linalg.norm(nm[i] - nm[j], axis=1)
    e = np.linalg.norm(meas[i] - meas[j], axis=1) - dn
    keys = ["all"] + [f"{c:g}" for c in DISTANCE_CLASSES_MM]
    return dict(zip(keys, map(_stats, acc))), np.stack([i, j], axis=1), dn, e


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
        P = pose_from_rt(np.eye(3), pts)
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
    if len(P) > MAX_ASSESS_POINTS:
        raise InputError(f"expected at most {MAX_ASSESS_POINTS} measured points (after "
                         f"averaging repeats), got {len(P)}: assess a part of the grid")
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
    stats, pairs, dn, de = _pair_distances(meas, nm, float(class_tolerance))
    rot_err = None
    if rot:
        from scipy.spatial.transform import Rotation

        r = Rotation.from_matrix(P[:, :3, :3])
        rot_err = (r * r.mean().inv()).magnitude()
    return GridAssessment(match=match, nominal_index=idx, measured=meas, nominal=nm,
                          residuals=reg.residuals, transform=reg.transform,
                          pair_index=pairs, nominal_distance=dn, distance_error=de,
                          jitter=jitter, rotation_errors=rot_err, n_rows=n_rows,
                          n_nonfinite=int((~ok).sum()), class_tolerance=float(class_tolerance),
                          distance_stats=stats)
