"""``--environment``: which environment terms a calibration fits, and how they are chosen.

Environment terms (:mod:`openemt.field._environment`) model what the workspace and the
acquisition add to the tracker's own field: induced dipoles of nearby metal, a gain
non-linearity per sensor channel, a coupling offset, and the coils' tilt (a board's; a dipole
model fits its coil moments' directions anyway). ``--environment`` takes

* ``auto`` (the default): the terms are chosen by cross-validation on the training rows only
  (the improved rig model: forward selection on position-grouped folds of the md rows,
  :func:`openemt.calibrate.select_terms`; a board: every candidate of
  :data:`PLANAR_CANDIDATES` on position-grouped folds of the fitted grid points); the choice and
  each candidate's held-out error go to the calibration's ``provenance["environment"]``;
* ``none``: no environment term;
* an explicit list such as ``dipoles:2,gain,tilt`` (``dipoles:K`` induced dipoles, ``gain``,
  ``offset``, ``tilt``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError

__all__ = ["ENVIRONMENT_NAMES", "PLANAR_CANDIDATES", "EnvironmentChoice",
           "improved_environment", "parse_environment", "planar_environment_cv"]

#: The names an explicit ``--environment`` list takes.
ENVIRONMENT_NAMES = ("dipoles", "gain", "offset", "tilt")

#: Folds of the board's cross-validation over grid points.
PLANAR_FOLDS = 4


@dataclass(frozen=True)
class EnvironmentChoice:
    """A parsed ``--environment``: ``mode`` (``auto``, ``none`` or ``given``) and, when given,
    ``dipoles`` (count), ``gain``, ``offset``, ``tilt``."""

    mode: str = "auto"
    dipoles: int = 0
    gain: bool = False
    offset: bool = False
    tilt: bool = False

    def names(self) -> list:
        return ([f"dipoles:{self.dipoles}"] if self.dipoles else []) + \
            [n for n in ("gain", "offset", "tilt") if getattr(self, n)]

    def label(self) -> str:
        return self.mode if self.mode != "given" else (",".join(self.names()) or "none")


def parse_environment(text) -> EnvironmentChoice:
    """``--environment`` text -> :class:`EnvironmentChoice` (InputError naming what was
    expected).

    Examples
    --------
    >>> parse_environment("dipoles:2,gain,tilt").names()
    ['dipoles:2', 'gain', 'tilt']
    >>> parse_environment("auto").mode
    'auto'
    """
    if isinstance(text, EnvironmentChoice):
        return text
    t = str("auto" if text is None else text).strip().lower()
    if t in ("auto", "none"):
        return EnvironmentChoice(mode=t)
    out = {"dipoles": 0, "gain": False, "offset": False, "tilt": False}
    for part in (p.strip() for p in t.split(",")):
        name, _, count = part.partition(":")
        if name not in ENVIRONMENT_NAMES or (count and name != "dipoles"):
            raise InputError(f"expected --environment auto, none or a list of "
                             f"{', '.join(ENVIRONMENT_NAMES)} (dipoles:K for K induced "
                             f"dipoles), got {text!r}")
        if name == "dipoles":
            try:
                k = int(count) if count else 1
            except ValueError:
                k = -1
            if not 1 <= k <= 8:
                raise InputError(f"expected dipoles:K with K from 1 to 8 in --environment, "
                                 f"got {part!r}")
            out["dipoles"] = k
        else:
            out[name] = True
    return EnvironmentChoice(mode="given", **out)


def improved_environment(choice: EnvironmentChoice) -> dict:
    """Keyword arguments of :func:`openemt.calibrate.improved_calibration` for a choice:
    ``auto`` tries :data:`openemt.calibrate.TERMS` by md cross-validation (as ``reproduce
    table2 --improved``), ``none`` fits the improved model alone, a given list fits those
    terms (one induced dipole at most)."""
    import dataclasses

    from ._heldout import IMPROVED_OPTIONS, TERMS

    if choice.mode == "auto":
        return {"terms": TERMS}
    if choice.mode == "none":
        return {}
    return {"options": dataclasses.replace(IMPROVED_OPTIONS, induced=bool(choice.dipoles),
                                           gain_nonlinear=choice.gain,
                                           coupling_offset=choice.offset)}


#: Candidate term sets ``--environment auto`` compares on a board, by name.
PLANAR_CANDIDATES = {"none": {}, "tilt": {"tilt": True}}


def _pose_vectors(points, axes) -> np.ndarray:
    """Pose vectors ``(N, 6)`` at ``points`` whose z axis is ``axes`` (the shortest rotation
    from z; a half turn about x for -z)."""
    u = np.asarray(axes, dtype=np.float64)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross([0.0, 0.0, 1.0], u)
    s = np.linalg.norm(w, axis=1)
    ang = np.arctan2(s, u[:, 2])
    k = np.where(s[:, None] > 1e-12, w / np.maximum(s, 1e-300)[:, None], [1.0, 0.0, 0.0])
    return np.c_[np.asarray(points, dtype=np.float64), k * ang[:, None]]


def planar_environment_cv(data, start_model, fit, *, folds: int = PLANAR_FOLDS,
                          candidates=None) -> tuple[str, dict]:
    """Cross-validate the board's candidate term sets on ``data`` (the grid points of the
    fit): folds of alternate regions of the volume (position-grouped), each candidate fitted
    on the others and solved on the fold. ``fit(data, start_model, **terms)`` fits one.

    Returns the chosen name (least pooled held-out position RMS; ties go to the simpler,
    earlier candidate) and ``{name: {"cv_position_rms_mm", "n"}}``.
    """
    from ..solve import GridData, planar_errors, prepare

    cands = PLANAR_CANDIDATES if candidates is None else candidates
    pts = np.asarray(data.points, dtype=np.float64)
    # position-grouped folds: the grid's points ordered along its widest axis, in blocks
    order = np.argsort(pts[:, int(np.argmax(np.ptp(pts, axis=0)))], kind="stable")
    fold = np.empty(len(pts), dtype=np.int64)
    fold[order] = np.arange(len(pts)) * folds // len(pts)
    fold = (fold + np.arange(len(pts)) % 2 * (folds // 2)) % folds    # interleave halves

    def subset(mask):
        return GridData(data.points[mask], data.axes[mask], data.couplings[mask],
                        data.coil_names)

    scores = {}
    for name, terms in cands.items():
        err, n = [], 0
        for k in range(folds):
            train, test = fold != k, fold == k
            if train.sum() < 7 or not test.any():
                continue
            f = fit(subset(train), start_model, **terms)
            # solved from the known pose: the model's error, not the cold start's, is scored
            held = subset(test)
            res = prepare(f.model)(held.couplings, _pose_vectors(held.points, held.axes))
            acc = planar_errors(f.model, held, result=res).summary()
            err.append(acc["position_rms_mm"] ** 2 * acc["n"])
            n += acc["n"]
        scores[name] = {"cv_position_rms_mm": float(np.sqrt(sum(err) / n)) if n else None,
                        "n": int(n)}
    finite = {k: v["cv_position_rms_mm"] for k, v in scores.items()
              if v["cv_position_rms_mm"] is not None and np.isfinite(v["cv_position_rms_mm"])}
    if not finite:
        return next(iter(cands)), scores
    best = min(finite.values())
    chosen = next(k for k in cands if k in finite and finite[k] <= best * (1 + 1e-9))
    return chosen, scores
