"""Cross-validation helpers: k-fold / leave-one-group-out splits and held-out residuals.

Corrections are judged on data not used in the fit. ``kfold_splits`` makes the splits;
``held_out_predictions`` fits on each training part and predicts the held-out part, so every
row gets exactly one prediction from a model that never saw it.

Pose data are often recorded at a few positions, with several orientations or repeated
samples at each (ILEMT: 5 stage rotations per grid point). Random folds would then hold out a
point whose near-duplicates stay in the training set, and cross-validation would only measure
repeatability, not interpolation. ``location_kfold`` therefore keeps the rows of one location
(positions within 2 % of the workspace span) in the same fold.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from .._errors import InputError
from ..evaluate import pose_error_magnitudes
from ..geometry import pose_from_rt

__all__ = [
    "MAX_FOLDS",
    "ROTATION_MOMENT_M",
    "apply_rotation_offsets",
    "check_folds",
    "held_out_poses",
    "held_out_predictions",
    "kfold_splits",
    "location_groups",
    "location_kfold",
    "normalizer",
    "pair_errors",
    "rotation_offsets",
    "take_rows",
]


#: Lever arm (m) that puts a rotation error on the same footing as a translation error in the
#: scores that choose between fits: 1 mrad counts like 0.1 mm.
ROTATION_MOMENT_M = 0.1

#: Most held-out splits of one evaluation (k of k-fold, or groups held out one at a time). The
#: order/smoothing selection runs inside every split (nested), so the cost grows with the
#: square of the count; leave-one-out on many pairs is refused rather than run for minutes.
MAX_FOLDS = 20


def check_folds(k: int, n_splits_name: str = "folds") -> int:
    """``k`` as int if ``2 <= k <= MAX_FOLDS``; InputError otherwise."""
    try:
        kk = int(k)
    except (TypeError, ValueError):
        raise InputError(f"expected an integer number of {n_splits_name}, got {k!r}") from None
    if not 2 <= kk <= MAX_FOLDS:
        raise InputError(f"expected 2 <= {n_splits_name} <= {MAX_FOLDS} (MAX_FOLDS), got {kk}")
    return kk


def kfold_splits(n: int, k: int = 5, *, seed: int = 0, groups=None, fold_groups=None
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Training/test index pairs for k-fold or leave-one-group-out cross-validation.

    Parameters
    ----------
    n : int
        Number of rows.
    k : int
        Number of folds (ignored when ``groups`` is given). ``2 <= k <= n``.
    seed : int
        Seed of the ``np.random.default_rng`` permutation that assigns rows to folds.
    groups : array_like, shape (n,), optional
        Group label per row (e.g. the file a row came from). Each group is held out once.
    fold_groups : array_like, shape (n,), optional
        Rows with the same label stay in the same fold of a k-fold split (groups are
        assigned to folds at random); used by :func:`location_kfold`.

    Returns
    -------
    list of (train, test) integer index arrays; the tests partition ``range(n)``.
    """
    if groups is not None:
        g = np.asarray(groups)
        if g.shape != (n,):
            raise InputError(f"expected `groups` of shape ({n},), got {g.shape}")
        labels = np.unique(g)
        if len(labels) < 2:
            raise InputError(f"expected at least 2 groups to hold out, got {len(labels)}")
        check_folds(len(labels), "groups held out")
        return [(np.flatnonzero(g != lab), np.flatnonzero(g == lab)) for lab in labels]
    k = check_folds(k)
    if not k <= n:
        raise InputError(f"expected 2 <= k <= n = {n} folds, got k = {k}")
    if fold_groups is not None:
        fg = np.asarray(fold_groups)
        if fg.shape != (n,):
            raise InputError(f"expected `fold_groups` of shape ({n},), got {fg.shape}")
        labels, inv = np.unique(fg, return_inverse=True)
        if len(labels) < k:
            raise InputError(f"expected at least k = {k} fold groups, got {len(labels)}")
        gperm = np.random.default_rng(seed).permutation(len(labels))
        gfold = np.empty(len(labels), dtype=int)
        for i, chunk in enumerate(np.array_split(gperm, k)):
            gfold[chunk] = i
        folds = [np.flatnonzero(gfold[inv] == i) for i in range(k)]
    else:
        perm = np.random.default_rng(seed).permutation(n)
        folds = np.array_split(perm, k)
    out = []
    for i in range(k):
        test = np.sort(folds[i])
        train = np.sort(np.concatenate([folds[j] for j in range(k) if j != i]))
        out.append((train, test))
    return out


def held_out_predictions(fit: Callable, predict: Callable, n: int, splits) -> list:
    """Run ``model = fit(train)`` and ``predict(model, test)`` over the splits.

    Returns the list of ``(test, prediction)`` pairs in split order. ``n`` is only used to check
    that the test parts cover every row once.
    """
    seen = np.zeros(n, dtype=int)
    out = []
    for train, test in splits:
        seen[test] += 1
        model = fit(train)
        out.append((test, predict(model, test)))
    if not np.all(seen == 1):
        raise InputError("expected the test folds to partition the rows, got overlaps or gaps")
    return out


def take_rows(rows, *arrays) -> tuple:
    """The rows ``rows`` of each array (None, no rotations, stays None)."""
    return tuple(None if a is None else np.asarray(a)[rows] for a in arrays)


def held_out_poses(fit: Callable, m, Rm, splits) -> tuple[np.ndarray, np.ndarray | None]:
    """Held-out predictions ``(xyz, R or None)`` of the measured positions ``m`` and
    rotations ``Rm``: each test part predicted by ``fit(train)`` of its split
    (:func:`held_out_predictions`)."""
    xyz = np.empty_like(m)
    R = None if Rm is None else np.empty_like(Rm)
    for rows, (px, pR) in held_out_predictions(
            fit, lambda model, rows: model.predict(*take_rows(rows, m, Rm)), len(m), splits):
        xyz[rows] = px
        if R is not None:
            R[rows] = pR
    return xyz, R


def pair_errors(xyz, R, reference_xyz, reference_R) -> tuple[np.ndarray, np.ndarray | None]:
    """Translation (m) and rotation (rad) error magnitudes of pose pairs, each shape (N,).

    The one pose-error definition of :func:`openemt.evaluate.pose_error_magnitudes`
    (``inv(P_measured) @ P_reference``). With ``R`` or ``reference_R`` None the pairs are
    positions only: the translation error is ``|xyz - reference_xyz|`` and the rotation error
    is None.
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(reference_xyz, dtype=np.float64).reshape(-1, 3)
    if R is None or reference_R is None:
        eye = np.broadcast_to(np.eye(3), (len(xyz), 3, 3))
        t, _ = pose_error_magnitudes(pose_from_rt(eye, xyz), pose_from_rt(eye, d))
        return t, None
    return pose_error_magnitudes(pose_from_rt(R, xyz), pose_from_rt(reference_R, d))


def rotation_offsets(R, reference_R) -> np.ndarray:
    """Rotation vectors ``rho`` with ``exp([rho]x) @ R = reference_R`` (left, source frame), (N, 3)."""
    D = reference_R @ np.swapaxes(R, -1, -2)
    return Rotation.from_matrix(D.reshape(-1, 3, 3)).as_rotvec()


def apply_rotation_offsets(rho, R) -> np.ndarray:
    """``exp([rho]x) @ R`` for rotation vectors (N, 3) and rotations (N, 3, 3)."""
    return Rotation.from_rotvec(np.asarray(rho).reshape(-1, 3)).as_matrix() @ R


def normalizer(xyz) -> tuple[np.ndarray, float]:
    """Centre (3,) and scale (float) that map the points into about [-1, 1]^3."""
    xyz = np.asarray(xyz, dtype=np.float64)
    center = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
    scale = float(np.max(np.abs(xyz - center)))
    return center, (scale if scale > 0 else 1.0)


def location_groups(xyz, tol_fraction: float = 0.02) -> np.ndarray:
    """Label rows whose positions are linked by distances below ``tol_fraction`` of the span.

    Returns integer labels, shape (N,): connected components of the graph joining positions
    closer than ``tol_fraction * max(extent)``.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    span = float(np.max(np.ptp(xyz, axis=0))) if n else 0.0
    if n < 2 or span <= 0:
        return np.zeros(n, dtype=int)
    pairs = cKDTree(xyz).query_pairs(tol_fraction * span, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(g, directed=False)[1]


def location_kfold(xyz, k: int = 5, *, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """k-fold splits that keep the rows of one location together (see the module docstring).

    Falls back to plain row folds when there are fewer than ``k`` distinct locations.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    k = min(int(k), n)
    g = location_groups(xyz)
    if len(np.unique(g)) >= k:
        return kfold_splits(n, k, seed=seed, fold_groups=g)
    return kfold_splits(n, k, seed=seed)
