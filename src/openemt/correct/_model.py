"""The serialisable ``Correction`` object, its fit with held-out errors, and JSON read/write.

``fit_correction`` fits one method (``dlt``, ``poly``, ``grid``, ``rbf``, ``bernstein``) to pose
pairs and
always reports the error on data not used in the fit (k-fold or leave-one-group-out, with the
whole fit, including any order/smoothing selection, repeated inside each fold) next to the
in-sample error, so overfitting is visible.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._result import Result, json_ready
from ..evaluate import error_summary
from ..geometry import check_points, check_poses, pose_from_rt
from ..io import atomic_path
from ._bernstein import (
    BOX_MARGIN,
    MAX_BERNSTEIN_DEGREE,
    BernsteinCorrection,
    data_box,
    fit_bernstein,
)
from ._crossval import (
    ROTATION_MOMENT_M,
    check_folds,
    held_out_poses,
    kfold_splits,
    location_kfold,
    pair_errors,
    take_rows,
)
from ._dlt import DltFit, fit_dlt
from ._dof import pair_requirements
from ._identity import IdentityCorrection, fit_identity
from ._lookup import MAX_RBF_CENTRES, GridCorrection, RbfCorrection, fit_grid, fit_rbf
from ._poly import PolynomialCorrection, fit_polynomial
from ._region import (
    FitBox,
    check_over_box,
    correct_rows,
    read_box,
    status_counts,
)

#: Pairs a fit (and its cross-validation) uses at most: beyond, a seeded random subsample of
#: this many (a warning says so). Every method's parameters (at most a few hundred) are
#: determined many times over by 10^5 spread pairs, and it keeps a fit of 10^6 or more pairs
#: to seconds and bounded memory (docs/correction.md#the-fitted-box).
MAX_FIT_PAIRS = 100_000

__all__ = [
    "CORRECTION_METHODS",
    "MAX_FIT_PAIRS",
    "MAX_RBF_CENTRES",
    "AppliedCorrection",
    "Correction",
    "evaluate_correction",
    "fit_correction",
    "held_out_score_mm",
    "read_correction",
    "write_correction",
]

#: Correction methods: name -> (fit function, fitted-model class).
CORRECTION_METHODS = {
    "none": (fit_identity, IdentityCorrection),
    "dlt": (lambda m, d, Rm, Rd, **kw: fit_dlt(m, d, **kw), DltFit),
    "poly": (fit_polynomial, PolynomialCorrection),
    "grid": (fit_grid, GridCorrection),
    "rbf": (fit_rbf, RbfCorrection),
    "bernstein": (fit_bernstein, BernsteinCorrection),
}

_FORMAT = "openemt.correction"
_VERSION = 2  # 2: the fitted box (``box``); version-1 files are read, see _v1_box

#: Highest polynomial order a correction file may name (C(order + 3, 3) monomials: 1771 at
#: order 20, far above the orders a fit selects, ``POLY_ORDERS``). A larger order in a file is
#: an error before anything is allocated.
MAX_POLY_ORDER = 20


def _numbers(p: dict, key: str, where: str, shape=None, *, optional: bool = False):
    """``params[key]`` as a finite float64 array (of ``shape``; ``None`` in it: any size)."""
    v = p.get(key)
    if v is None:
        if optional:
            return None
        raise InputError(f"{where}expected `params.{key}` as finite numbers, got "
                         f"{'null' if key in p else 'no such field'}")
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}expected `params.{key}` as finite numbers, got null or "
                         f"non-numbers") from None
    if not np.all(np.isfinite(a)):
        raise InputError(f"{where}expected finite numbers in `params.{key}`, got "
                         f"{int((~np.isfinite(a)).sum())} NaN/inf")
    if shape is not None and (a.ndim != len(shape) or any(
            s is not None and s != n for s, n in zip(shape, a.shape))):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"{where}expected `params.{key}` of shape {want}, got {a.shape}")
    return a


def _order(p: dict, key: str, coef_key: str, where: str, *, optional: bool,
           limit: int = MAX_POLY_ORDER, name: str = " (MAX_POLY_ORDER)"):
    """``params[key]``, an integer ``0..limit``; None when it may be absent and is (its
    coefficients ``params[coef_key]`` then null too)."""
    v = p.get(key)
    if v is None and optional:
        if p.get(coef_key) is not None:
            raise InputError(f"{where}expected `params.{coef_key}` null without "
                             f"`params.{key}`, got coefficients")
        return None
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= limit:
        raise InputError(f"{where}expected `params.{key}` an integer 0..{limit}{name}, got "
                         f"{v!r}")
    return v


def _positive_scale(p: dict, where: str) -> None:
    s = _numbers(p, "scale", where, ())
    if not s != 0:
        raise InputError(f"{where}expected a non-zero finite `params.scale`, got {float(s)}")


def _check_params(method: str, p: dict, where: str) -> None:
    """Validate a correction's parameters before they are used (shapes, finite coefficients,
    bounded sizes); raises InputError naming the field."""
    if method == "dlt":
        from ..io._calibration import check_correction_matrix

        check_correction_matrix(p.get("matrix"), "params.matrix", where)
        return
    if method in ("poly", "rbf"):
        _numbers(p, "center", where, (3,))
        _positive_scale(p, where)
    if method == "poly":
        from ._poly import monomial_exponents

        mp = p.get("max_power")
        if mp is not None and (not isinstance(mp, list) or len(mp) != 3 or not all(
                m is None or (isinstance(m, int) and not isinstance(m, bool) and m >= 0)
                for m in mp)):
            raise InputError(f"{where}expected `params.max_power` null or 3 entries of null or "
                             f"a non-negative integer, got {mp!r}")
        for order_key, coef_key, optional in (("pos_order", "pos_coef", False),
                                              ("rot_order", "rot_coef", True)):
            order = _order(p, order_key, coef_key, where, optional=optional)
            if order is not None:
                _numbers(p, coef_key, where, (len(monomial_exponents(order, mp)), 3))
    if method in ("bernstein", "grid"):
        lo = _numbers(p, "lower", where, (3,))
        hi = _numbers(p, "upper", where, (3,))
        if not np.all(lo < hi):
            raise InputError(f"{where}expected `params.lower` < `params.upper` on every axis, "
                             f"got {lo.tolist()} and {hi.tolist()}")
    if method == "bernstein":
        for deg_key, coef_key, optional in (("pos_degree", "pos_coef", False),
                                            ("rot_degree", "rot_coef", True)):
            deg = _order(p, deg_key, coef_key, where, optional=optional,
                         limit=MAX_BERNSTEIN_DEGREE, name="")
            if deg is not None:
                _numbers(p, coef_key, where, ((deg + 1) ** 3, 3))
    elif method == "grid":
        shape = p.get("shape")
        if not isinstance(shape, list) or len(shape) != 3 or not all(
                isinstance(s, int) and not isinstance(s, bool) and s >= 2 for s in shape):
            raise InputError(f"{where}expected `params.shape` 3 integers >= 2, got {shape!r}")
        vals = _numbers(p, "values", where)
        if vals.ndim != 4 or list(vals.shape[:3]) != shape or vals.shape[3] not in (3, 6):
            raise InputError(f"{where}expected `params.values` of shape ({shape[0]}, "
                             f"{shape[1]}, {shape[2]}, 3 or 6), got {vals.shape}")
        _numbers(p, "smoothing", where, ())
    elif method == "rbf":
        n_pts = len(p["points"]) if isinstance(p.get("points"), list) else 0
        if n_pts > MAX_RBF_CENTRES:
            raise InputError(f"{where}expected at most MAX_RBF_CENTRES = {MAX_RBF_CENTRES} RBF "
                             f"centres (`params.points`), got {n_pts}: evaluating it would "
                             f"need a dense {n_pts} x {n_pts} matrix; refit it (a fit uses at "
                             f"most {MAX_RBF_CENTRES} centres)")
        pts = _numbers(p, "points", where, (None, 3))
        vals = _numbers(p, "values", where)
        if vals.ndim != 2 or vals.shape[0] != len(pts) or vals.shape[1] not in (3, 6):
            raise InputError(f"{where}expected `params.values` of shape ({len(pts)}, 3 or 6), "
                             f"got {vals.shape}")
        _numbers(p, "smoothing", where, ())


def _split_pairs(measured, reference):
    """Validate pairs; return (m_xyz, m_R or None, d_xyz, d_R or None, is_pose)."""
    a = np.asarray(measured)
    if a.ndim == 3:
        M = check_poses(measured, "measured")
        D = check_poses(reference, "reference")
        if D.shape != M.shape:
            raise InputError(f"expected `reference` of shape {M.shape}, got {D.shape}")
        return M[:, :3, 3], M[:, :3, :3], D[:, :3, 3], D[:, :3, :3], True
    m = check_points(measured, "measured")
    d = check_points(reference, "reference")
    if m.ndim != 2:
        raise InputError(f"expected `measured` of shape (N, 3) or (N, 4, 4), got {m.shape}")
    if d.shape != m.shape:
        raise InputError(f"expected `reference` of shape {m.shape}, got {d.shape}")
    return m, None, d, None, False


def _summary(xyz, R, d_xyz, d_R) -> dict:
    """``error_summary`` of the pose errors (position-only pairs: translation keys only)."""
    et, er = pair_errors(xyz, R, d_xyz, d_R)
    if er is None:
        s = error_summary(et, np.zeros(len(xyz)))
        return {k: v for k, v in s.items() if not k.startswith("rot_")}
    return error_summary(et, er)


def held_out_score_mm(summary: dict) -> float:
    """One number to compare fits: RMS translation (mm) + RMS rotation (rad) x 100 mm
    (:data:`ROTATION_MOMENT_M`); translation alone for position-only pairs."""
    s = float(summary["trans_rms_mm"])
    if "rot_rms_deg" in summary:
        s += 1e3 * ROTATION_MOMENT_M * np.deg2rad(float(summary["rot_rms_deg"]))
    return s


def _warnings(method: str, n: int, params: dict, held: dict | None) -> tuple[list, bool, dict]:
    """Warnings about too few pairs and about a correction worse held out than none."""
    req = pair_requirements(method, params)
    out = []
    if n < req["min_pairs"]:
        out.append(f"{method}: {n} pose pairs are fewer than the {req['min_pairs']} recommended "
                   f"for its {req['parameters_per_coordinate']} parameters per coordinate "
                   f"(docs/correction.md#how-many-pairs); its errors are unreliable")
    worse = False
    if held is not None and method != "none":
        for key, unit in (("trans_rms_mm", "mm"), ("rot_rms_deg", "deg")):
            c, u = held["corrected"].get(key), held["uncorrected"].get(key)
            if c is not None and u is not None and np.isfinite(c) and c > u * (1 + 1e-9):
                worse = True
                what = "translation" if key.startswith("trans") else "rotation"
                out.append(f"{method}: held-out {what} error {c:.4f} {unit} is worse than no "
                           f"correction ({u:.4f} {unit})")
    return out, worse, req


def _v1_box(method: str, model) -> FitBox | None:
    """The fitted box of a version-1 file (which did not store it), where the parameters
    determine it: an RBF's centres, a grid's or Bernstein basis's own box; None (unknown) for
    a DLT or polynomial."""
    if method == "rbf":
        b = FitBox.of(model.center + model.scale * model.points)
        return FitBox(b.lower, b.upper, "params")
    if method in ("grid", "bernstein"):
        return FitBox(np.asarray(model.lower), np.asarray(model.upper), "params")
    return None


@dataclass(frozen=True)
class AppliedCorrection(Result):
    """Poses (or positions) after :meth:`Correction.correct`, with a status per row.

    Attributes
    ----------
    values : ndarray
        Same shape as the input; rows not corrected (outside the box, non-finite, rejected)
        hold their input values.
    status : ndarray of int8, shape (N,)
        Per-row code of :data:`openemt.correct.STATUS`: ``corrected``, ``extrapolated``
        (outside the box, within the margin, corrected), ``outside_box`` (passed through),
        ``nonfinite_input``, ``rejected`` (the correction came out non-finite or moved the
        position by more than the box's diagonal; passed through), ``unchecked`` (corrected,
        no box known).
    counts : dict
        ``{status name: rows}``.
    """

    values: np.ndarray
    status: np.ndarray
    counts: dict
    _not_in_dict = ("values", "status")


@dataclass(frozen=True)
class Correction:
    """A fitted output correction of positions (and orientations for poly/grid/rbf).

    Attributes
    ----------
    method : str
        ``"none"``, ``"dlt"``, ``"poly"``, ``"bernstein"``, ``"grid"`` or ``"rbf"``.
    params : dict
        The fitted parameters (SI units; arrays), as the method's ``to_params`` gives them.
    stats : dict
        Fit statistics: ``in_sample`` and ``held_out`` error summaries (mm/deg keys of
        :func:`openemt.evaluate.error_summary`) of the uncorrected and corrected pairs.
    meta : dict
        Free-form provenance (input files, options).
    box : FitBox or None
        The bounding box of the measured positions it was fitted on (None: unknown, a
        version-1 DLT or polynomial file). See :meth:`correct`.
    """

    method: str
    params: dict
    stats: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    box: FitBox | None = None

    def __post_init__(self):
        if self.method not in CORRECTION_METHODS:
            raise InputError(f"expected a correction method in {sorted(CORRECTION_METHODS)}, "
                             f"got {self.method!r}")

    @property
    def model(self):
        """The fitted model object (``DltFit``, ``PolynomialCorrection``, ...)."""
        cache = self.__dict__.get("_model")
        if cache is None:
            cache = CORRECTION_METHODS[self.method][1].from_params(self.params)
            object.__setattr__(self, "_model", cache)
        return cache

    @property
    def corrects_orientation(self) -> bool:
        p = self.params
        if self.method in ("none", "dlt"):
            return False
        if self.method in ("poly", "bernstein"):
            return p.get("rot_coef") is not None
        return np.shape(p["values"])[-1] == 6

    def correct(self, measured, *, extrapolate_margin: float = 0.0,
                allow_unknown_box: bool = False) -> AppliedCorrection:
        """Correct measured poses ``(N, 4, 4)`` or positions ``(N, 3)`` inside the fitted box.

        Rows inside the box are corrected; rows outside it by at most ``extrapolate_margin``
        (m, along the worst axis) are corrected and flagged ``extrapolated``; rows further out,
        non-finite rows and rows whose correction comes out non-finite or moves the position by
        more than the box's diagonal (at least 50 mm) keep their input values, each with its
        status (:class:`AppliedCorrection`). Without a known box (a version-1 DLT or polynomial
        file) this is an InputError unless ``allow_unknown_box``; every finite row is then
        corrected and flagged ``unchecked``. Work is done in blocks of rows (bounded memory).

        Examples
        --------
        >>> import numpy as np
        >>> from openemt.bench._correct import distorted_poses
        >>> from openemt.correct import fit_correction
        >>> measured, reference = distorted_poses(100, np.random.default_rng(0))
        >>> corr = fit_correction(measured, reference, "poly", order=2, rot_order=1,
        ...                       cross_validate=False)
        >>> far = measured[:3].copy()
        >>> far[1, 0, 3] += 1.0  # 1 m outside the fitted box
        >>> res = corr.correct(far)
        >>> res.status.tolist(), res.counts["outside_box"]
        ([0, 2, 0], 1)
        >>> bool(np.array_equal(res.values[1], far[1]))  # passed through as read
        True
        """
        margin = check_margin(extrapolate_margin)
        if self.box is None and not allow_unknown_box and self.method != "none":
            raise InputError(f"expected a correction that records the box it was fitted on, "
                             f"got a version-1 {self.method} file without one: refit it with "
                             f"'openemt correct fit', or allow correcting everywhere as before "
                             f"(--allow-unknown-box)")
        domain = (self.model.lower, self.model.upper) if self.method == "bernstein" else None
        a = np.asarray(measured)
        if a.ndim == 3:
            P = check_poses(measured, "measured")
            xyz, R, st = correct_rows(self.model, self.box, P[:, :3, 3], P[:, :3, :3], margin,
                                      domain)
            out = P.copy()
            out[:, :3, :3] = R
            out[:, :3, 3] = xyz
        else:
            m = check_points(measured, "measured")
            xyz, _, st = correct_rows(self.model, self.box, m.reshape(-1, 3), None, margin,
                                      domain)
            out = xyz[0] if m.ndim == 1 else xyz
        return AppliedCorrection(values=out, status=st, counts=status_counts(st))

    def apply(self, measured, *, extrapolate_margin: float | None = None) -> np.ndarray:
        """Correct measured poses ``(N, 4, 4)`` or positions ``(N, 3)``; returns the same shape.

        Without ``extrapolate_margin`` the model is evaluated at every row, as it always was:
        outside the fitted box that is extrapolation (a polynomial moves a pose 1 m outside a
        0.1 m box by centimetres); for new data use :meth:`correct`, which also says per row
        what was corrected. With ``extrapolate_margin`` (m) this is ``correct(...).values``:
        poses outside the box beyond the margin and non-finite rows come back unchanged.
        Orientation is corrected only by methods fitted with orientations
        (``corrects_orientation``); otherwise it is passed through.
        """
        if extrapolate_margin is not None:
            return self.correct(measured, extrapolate_margin=extrapolate_margin,
                                allow_unknown_box=True).values
        a = np.asarray(measured)
        if a.ndim == 3:
            P = check_poses(measured, "measured")
            xyz, R = self.model.predict(P[:, :3, 3], P[:, :3, :3])
            return pose_from_rt(R, xyz)
        m = check_points(measured, "measured")
        single = m.ndim == 1
        xyz, _ = self.model.predict(m.reshape(-1, 3), None)
        return xyz[0] if single else xyz

    def to_dict(self) -> dict:
        return {"format": _FORMAT, "version": _VERSION, "method": self.method,
                "params": json_ready(self.params),
                "box": None if self.box is None else self.box.to_dict(),
                "stats": json_ready(self.stats), "meta": json_ready(self.meta)}

    @classmethod
    def from_dict(cls, d: dict, source: str = "") -> Correction:
        """Validate a correction document (as :func:`write_correction` writes it) and build the
        correction; ``source`` names the file in error messages. The model is checked over its
        box (:func:`openemt.correct._region.check_over_box`): finite and not degenerate."""
        where = f"correction file {source}: " if source else "correction: "
        if not isinstance(d, dict):
            raise InputError(f"{where}expected a JSON object, got {type(d).__name__}")
        if d.get("format") != _FORMAT:
            raise InputError(f"{where}expected format {_FORMAT!r}, got {d.get('format')!r}")
        version = d.get("version")
        if not isinstance(version, int) or isinstance(version, bool) or not (
                1 <= version <= _VERSION):
            raise InputError(f"{where}expected version 1..{_VERSION}, got {version!r}")
        method = d.get("method")
        if not isinstance(method, str) or method not in CORRECTION_METHODS:
            raise InputError(f"{where}expected `method` in {sorted(CORRECTION_METHODS)}, got "
                             f"{method!r}")
        params = d.get("params")
        if not isinstance(params, dict):
            raise InputError(f"{where}expected `params` to be an object, got "
                             f"{type(params).__name__}")
        for name in ("stats", "meta"):
            if d.get(name) is not None and not isinstance(d[name], dict):
                raise InputError(f"{where}expected `{name}` to be an object, got "
                                 f"{type(d[name]).__name__}")
        box = read_box(d["box"], where) if d.get("box") is not None else None
        try:
            _check_params(method, params, where)
            obj = cls(method=method, params=dict(params),
                      stats=dict(d.get("stats") or {}), meta=dict(d.get("meta") or {}))
            # normalise params through the model so arrays have their numpy types again
            obj = cls(method=obj.method, params=obj.model.to_params(), stats=obj.stats,
                      meta=obj.meta)
            if box is None and version == 1:
                box = _v1_box(method, obj.model)
            obj = replace(obj, box=box)
        except InputError:
            raise
        except (TypeError, KeyError, ValueError) as exc:
            # a parameter of the wrong JSON type or form (a string, object or null where
            # numbers belong) reached the model's constructor: the file is malformed
            raise InputError(f"{where}expected the `params` of a {method!r} correction as "
                             f"openemt writes them, got a malformed value "
                             f"({type(exc).__name__}: {exc})") from None
        check = box
        if check is None and method == "poly":  # no box: the region its scaling was made for
            m = obj.model
            check = FitBox(m.center - abs(m.scale), m.center + abs(m.scale), "params")
        if check is not None and method != "none":
            check_over_box(method, obj.model, check, where)
        return obj


def check_margin(margin) -> float:
    """``extrapolate_margin`` as a finite float >= 0 (m); InputError otherwise."""
    try:
        v = float(margin)
    except (TypeError, ValueError):
        raise InputError(f"expected an extrapolation margin in m (a number >= 0), got "
                         f"{margin!r}") from None
    if not (np.isfinite(v) and v >= 0):
        raise InputError(f"expected a finite extrapolation margin >= 0 m, got {v}")
    return v


def _fit_model(method, m, Rm, d, Rd, options):
    fit = CORRECTION_METHODS[method][0]
    return fit(m, d, Rm, Rd, **options)


def fit_correction(measured, reference, method: str = "poly", *, k: int = 5, seed: int = 0,
                   groups=None, cross_validate: bool = True, meta: dict | None = None,
                   **options) -> Correction:
    """Fit an output correction to (measured, reference) pairs and report held-out errors.

    Parameters
    ----------
    measured, reference : array_like, shape (N, 4, 4) or (N, 3)
        Measured and reference poses (or positions only), SI units.
    method : {"none", "dlt", "poly", "grid", "rbf", "bernstein"}
    k : int
        Folds of the held-out evaluation (k-fold keeping the rows of one location together,
        see :func:`location_kfold`; shuffled with ``seed``); 2 to ``MAX_FOLDS``.
    seed : int
    groups : array_like, shape (N,), optional
        Hold out one group (e.g. file) at a time instead of k random folds.
    cross_validate : bool
        Compute the held-out statistics (default). Disable only for speed.
    meta : dict, optional
        Provenance stored in the result.
    **options
        Passed to the method's fit (e.g. ``order``, ``rot_order`` for poly; ``shape``,
        ``smoothing`` for grid; ``smoothing`` for rbf; ``refine`` for dlt; ``degree``,
        ``rot_degree``, ``margin`` for bernstein).

    Returns
    -------
    Correction
        ``stats["in_sample"]`` and ``stats["held_out"]`` hold ``uncorrected`` (= the method
        ``none``) and ``corrected`` error summaries (mm, deg). ``stats["warnings"]`` lists
        too few pairs for the method (``stats["requirements"]``) and a held-out error worse
        than no correction (then ``stats["worse_than_none"]`` is True).

    Examples
    --------
    Correct a smoothly distorted tracker (about 1 mm RMS, the simulated distortion of
    ``openemt bench correct``) with a second-order polynomial; the held-out error is the one
    to trust:

    >>> import numpy as np
    >>> from openemt.bench._correct import distorted_poses
    >>> from openemt.correct import fit_correction
    >>> measured, reference = distorted_poses(300, np.random.default_rng(0))
    >>> corr = fit_correction(measured, reference, "poly", order=2)
    >>> held_out = corr.stats["held_out"]
    >>> round(held_out["uncorrected"]["trans_rms_mm"], 2), round(held_out["corrected"]["trans_rms_mm"], 2)
    (0.95, 0.2)
    >>> corr.apply(measured).shape
    (300, 4, 4)
    """
    if method not in CORRECTION_METHODS:
        raise InputError(f"expected a correction method in {sorted(CORRECTION_METHODS)}, "
                         f"got {method!r}")
    if groups is None and cross_validate:
        k = check_folds(k)
    m, Rm, d, Rd, _ = _split_pairs(measured, reference)
    ok = np.all(np.isfinite(m), axis=1) & np.all(np.isfinite(d), axis=1)
    if Rm is not None:
        ok &= np.all(np.isfinite(Rm), axis=(1, 2)) & np.all(np.isfinite(Rd), axis=(1, 2))
    n_dropped = int((~ok).sum())
    if n_dropped:
        m, d, Rm, Rd, groups = take_rows(ok, m, d, Rm, Rd, groups)
    n_pairs = len(m)
    if n_pairs > MAX_FIT_PAIRS:
        keep = np.sort(np.random.default_rng(seed).choice(n_pairs, MAX_FIT_PAIRS, replace=False))
        m, d, Rm, Rd, groups = take_rows(keep, m, d, Rm, Rd, groups)
    if method != "dlt":  # inner selection (order / smoothing) uses the same folds setting
        options = {"k": k, "seed": seed, **options}
    if method == "bernstein" and options.get("box") is None:
        # one box for the fit and all its folds: a held-out point is never outside it
        options["box"] = data_box(m, options.pop("margin", BOX_MARGIN))
    model = _fit_model(method, m, Rm, d, Rd, options)
    params = model.to_params()
    xyz_fit, R_fit = model.predict(m, Rm)
    stats = {"n": len(m), "n_dropped_nonfinite": n_dropped,
             "in_sample": {"uncorrected": _summary(m, Rm, d, Rd),
                           "corrected": _summary(xyz_fit, R_fit, d, Rd)}}
    if cross_validate:
        if groups is not None:
            splits = kfold_splits(len(m), seed=seed, groups=groups)
            scheme = "leave-one-group-out"
        else:
            splits = location_kfold(m, k, seed=seed)
            scheme = f"{len(splits)}-fold by location"

        xyz_ho, R_ho = held_out_poses(
            lambda rows: _fit_model(method, *take_rows(rows, m, Rm, d, Rd), options), m, Rm,
            splits)
        stats["held_out"] = {
            "scheme": scheme,
            "n_folds": len(splits), "seed": int(seed),
            "uncorrected": _summary(m, Rm, d, Rd),
            "corrected": _summary(xyz_ho, R_ho, d, Rd)}
    warn, worse, req = _warnings(method, len(m), params, stats.get("held_out"))
    if n_pairs > MAX_FIT_PAIRS:
        stats["n_pairs_given"] = n_pairs
        warn.append(f"{n_pairs} pairs exceed MAX_FIT_PAIRS = {MAX_FIT_PAIRS}: fitted and "
                    f"cross-validated on a random subsample of {MAX_FIT_PAIRS} (seed {seed})")
    if getattr(model, "n_centres_of", None):
        warn.append(f"rbf: {model.n_centres_of} pairs exceed MAX_RBF_CENTRES = "
                    f"{MAX_RBF_CENTRES}: its centres are a random subsample of "
                    f"{len(model.points)} (seed {seed}); the errors are over all pairs")
    stats.update({"requirements": req, "warnings": warn, "worse_than_none": worse})
    box = FitBox.of(m)
    if method != "none":
        check_over_box(method, model, box, f"the fitted {method} correction: ")
    return Correction(method=method, params=params, stats=stats, meta=dict(meta or {}),
                      box=box)


def evaluate_correction(correction: Correction, measured, reference) -> dict:
    """Error summaries of held-out pairs before and after applying ``correction``."""
    m, Rm, d, Rd, _ = _split_pairs(measured, reference)
    xyz, R = correction.model.predict(m, Rm)
    return {"uncorrected": _summary(m, Rm, d, Rd), "corrected": _summary(xyz, R, d, Rd)}


def write_correction(correction: Correction, path) -> None:
    """Write a correction as JSON (atomically)."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(correction.to_dict(), indent=1) + "\n")


def read_correction(path) -> Correction:
    """Read a correction written by :func:`write_correction`, validated
    (docs/correction.md#correction-files): known format version, finite coefficients, non-zero
    scale, polynomial orders at most ``MAX_POLY_ORDER``, sizes consistent."""
    from ..io._jsontext import load_json_file

    path = Path(path)
    d = load_json_file(path, "a JSON correction file")
    return Correction.from_dict(d, path.name)
