"""Output correction on pose pairs (measured, reference): DLT, polynomials (total-degree and
tensor-product Bernstein), lookup tables.

Independent of any magnetic model: the corrections work on the pose output of any tracker
(ILEMT, NDI Aurora, Polhemus, ...) given reference poses. See docs/correction.md.
"""

from ._bernstein import (
    BERNSTEIN_DEGREES,
    BernsteinCorrection,
    bernstein_basis,
    data_box,
    fit_bernstein,
)
from ._crossval import MAX_FOLDS, check_folds, kfold_splits, location_groups, location_kfold
from ._dlt import DltFit, apply_linear_correction, fit_dlt, linear_correction_rms
from ._dof import MIN_PAIRS_FACTOR, pair_requirements
from ._identity import IdentityCorrection
from ._lookup import GridCorrection, RbfCorrection, fit_grid, fit_rbf
from ._model import (
    CORRECTION_METHODS,
    MAX_FIT_PAIRS,
    MAX_RBF_CENTRES,
    AppliedCorrection,
    Correction,
    check_margin,
    evaluate_correction,
    fit_correction,
    held_out_score_mm,
    read_correction,
    write_correction,
)
from ._poly import (
    POLY_ORDERS,
    PolynomialCorrection,
    axis_levels,
    fit_polynomial,
    monomial_exponents,
)
from ._region import MAX_SHIFT_FLOOR_M, STATUS, FitBox, check_over_box, max_shift
from ._select import AUTO_METHODS, fit_auto_correction
from ._workflow import (
    ApplyOptions,
    ApplyResult,
    FitOptions,
    FitResult,
    apply_correction_file,
    fit_correction_files,
)

__all__ = [
    "AUTO_METHODS",
    "BERNSTEIN_DEGREES",
    "CORRECTION_METHODS",
    "MAX_FOLDS",
    "MAX_FIT_PAIRS",
    "MAX_RBF_CENTRES",
    "MAX_SHIFT_FLOOR_M",
    "MIN_PAIRS_FACTOR",
    "POLY_ORDERS",
    "STATUS",
    "AppliedCorrection",
    "ApplyOptions",
    "ApplyResult",
    "BernsteinCorrection",
    "Correction",
    "FitBox",
    "FitOptions",
    "FitResult",
    "DltFit",
    "GridCorrection",
    "IdentityCorrection",
    "PolynomialCorrection",
    "RbfCorrection",
    "apply_correction_file",
    "apply_linear_correction",
    "axis_levels",
    "bernstein_basis",
    "check_folds",
    "check_margin",
    "check_over_box",
    "data_box",
    "evaluate_correction",
    "fit_auto_correction",
    "fit_bernstein",
    "fit_correction",
    "fit_correction_files",
    "fit_dlt",
    "fit_grid",
    "fit_polynomial",
    "fit_rbf",
    "held_out_score_mm",
    "kfold_splits",
    "linear_correction_rms",
    "location_groups",
    "location_kfold",
    "max_shift",
    "monomial_exponents",
    "pair_requirements",
    "read_correction",
    "write_correction",
]
