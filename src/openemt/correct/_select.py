"""``method="auto"``: fit every method and keep the one with the lowest held-out error,
"none" included, so that the chosen correction is never worse held out than no correction
(docs/correction.md#auto).

The held-out figures of the candidates come from the same splits (same folds and seed, or the
same groups). Choosing the best of several candidates by those figures makes the winner's own
figure slightly optimistic; score the correction on a separate recording
(``openemt correct apply`` with reference columns) for an unbiased figure.
"""

from __future__ import annotations

from .._errors import InputError
from ._model import Correction, fit_correction, held_out_score_mm

__all__ = ["AUTO_METHODS", "fit_auto_correction"]

#: Candidates of ``auto``, simplest first (ties keep the simpler one).
AUTO_METHODS = ("none", "dlt", "poly", "bernstein", "grid", "rbf")


def fit_auto_correction(measured, reference, *, methods=AUTO_METHODS, k: int = 5,
                        seed: int = 0, groups=None, meta: dict | None = None,
                        method_options: dict | None = None) -> Correction:
    """Fit the candidates and return the one with the lowest held-out score.

    Parameters
    ----------
    measured, reference, k, seed, groups, meta
        As :func:`openemt.correct.fit_correction`.
    methods : sequence of str
        Candidates; ``"none"`` is always added.
    method_options : dict, optional
        ``{method: {option: value}}`` passed to the candidate's fit.

    Returns
    -------
    Correction
        The winner, with ``stats["auto"]``: the score rule, the winner and per candidate its
        in-sample and held-out summaries, score (mm), warnings, or the reason it was skipped
        (too few pairs). ``stats["warnings"]`` are the winner's.
    """
    methods = ["none"] + [m for m in methods if m != "none"]
    opts = method_options or {}
    best, best_score = None, float("inf")
    table = {}
    for method in methods:
        try:
            c = fit_correction(measured, reference, method, k=k, seed=seed, groups=groups,
                               meta=meta, **opts.get(method, {}))
        except InputError as exc:
            if method == "none":
                raise
            table[method] = {"skipped": str(exc)}
            continue
        st = c.stats
        score = held_out_score_mm(st["held_out"]["corrected"])
        table[method] = {"in_sample": st["in_sample"]["corrected"],
                         "held_out": st["held_out"]["corrected"], "score_mm": score,
                         "warnings": st["warnings"]}
        if score < best_score - 1e-12:
            best, best_score = c, score
    stats = dict(best.stats)
    stats["auto"] = {"score": "held-out trans_rms_mm + rot_rms (rad) x 100 mm",
                     "chosen": best.method, "candidates": table}
    return Correction(method=best.method, params=best.params, stats=stats, box=best.box,
                      meta={**best.meta, "method_requested": "auto"})
