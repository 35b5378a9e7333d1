"""Pairing the rows of two pose recordings (measured tracker, reference tracker or robot)."""

from __future__ import annotations

import numpy as np

from .._errors import InputError

__all__ = ["MATCH_MODES", "pair_rows"]

#: ``order``: row i with row i; ``frame``: rows with the same frame number.
MATCH_MODES = ("order", "frame")


def pair_rows(n_measured: int, n_reference: int, *, match: str = "order",
              measured_frame=None, reference_frame=None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Row indices ``(i, j)`` pairing measured row ``i[k]`` with reference row ``j[k]``.

    Parameters
    ----------
    n_measured, n_reference : int
        Row counts.
    match : {"order", "frame"}
        ``order`` needs equal row counts; ``frame`` pairs equal, non-negative frame numbers
        (each must be unique within its recording) and counts the rows left unpaired.
    measured_frame, reference_frame : array_like of int, optional
        Frame numbers (needed for ``frame``).

    Returns
    -------
    (i, j, info) with ``info = {"match", "n_unmatched_measured", "n_unmatched_reference"}``.
    """
    if match not in MATCH_MODES:
        raise InputError(f"expected match in {MATCH_MODES}, got {match!r}")
    if match == "order":
        if n_measured != n_reference:
            raise InputError(f"expected the same number of rows to pair by order, got "
                             f"{n_measured} measured and {n_reference} reference rows "
                             f"(pair by frame number with --match frame)")
        idx = np.arange(n_measured)
        return idx, idx.copy(), {"match": match, "n_unmatched_measured": 0,
                                 "n_unmatched_reference": 0}
    if measured_frame is None or reference_frame is None:
        raise InputError("expected frame numbers in both recordings to pair by frame, got "
                         "a recording without them")
    fm = np.asarray(measured_frame, dtype=np.int64)
    fr = np.asarray(reference_frame, dtype=np.int64)
    for name, f in (("measured", fm), ("reference", fr)):
        u, c = np.unique(f[f >= 0], return_counts=True)
        if not len(u):
            raise InputError(f"expected frame numbers in the {name} recording, got none")
        if np.any(c > 1):
            raise InputError(f"expected unique frame numbers in the {name} recording, got "
                             f"frame {int(u[c > 1][0])} {int(c.max())} times")
    common, i, j = np.intersect1d(fm[fm >= 0], fr[fr >= 0], return_indices=True)
    mi = np.flatnonzero(fm >= 0)[i]
    rj = np.flatnonzero(fr >= 0)[j]
    return mi, rj, {"match": match, "n_unmatched_measured": int(n_measured - len(common)),
                    "n_unmatched_reference": int(n_reference - len(common))}
