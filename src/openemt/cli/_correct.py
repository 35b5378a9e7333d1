"""``openemt correct fit|apply``: output correction of tracker poses against a reference.

``fit`` reads pose-pair files (CSV with ``ref_`` columns, or pose datasets; ``openemt align``
writes them), fits a correction (or picks one, "none" included, with ``--method auto``) and
prints its in-sample and held-out errors beside those of no correction. ``apply`` corrects the
poses inside the correction's fitted box, passes the others through, and writes a status per
row. The workflows are :func:`openemt.correct.fit_correction_files` and
:func:`openemt.correct.apply_correction_file` (docs/correction.md).
"""

from __future__ import annotations

from ..correct import ApplyOptions, FitOptions, apply_correction_file, fit_correction_files
from ._common import add_actions, add_command

__all__ = ["register"]


def register(sub) -> None:
    add_actions(add_command(sub, "correct", description=__doc__.splitlines()[0]), (
        ("fit", "fit a correction to pose pairs (CSV)", FitOptions, fit_correction_files),
        ("apply", "apply a correction to poses inside its fitted box", ApplyOptions,
         apply_correction_file)))
