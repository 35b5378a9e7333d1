"""Output correction on pose pairs (measured, reference): DLT, polynomials (total-degree and
tensor-product Bernstein), lookup tables.

Independent of any magnetic model: the corrections work on the pose output of any tracker
(ILEMT, NDI Aurora, Polhemus, ...) given reference poses. See docs/correction.md.
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._bernstein": ("BERNSTEIN_DEGREES", "BernsteinCorrection", "bernstein_basis", "data_box",
                    "fit_bernstein"),
    "._crossval": ("MAX_FOLDS", "check_folds", "kfold_splits", "location_groups", "location_kfold"),
    "._dlt": ("DltFit", "apply_linear_correction", "fit_dlt", "linear_correction_rms"),
    "._dof": ("MIN_PAIRS_FACTOR", "pair_requirements"),
    "._identity": ("IdentityCorrection",),
    "._lookup": ("GridCorrection", "RbfCorrection", "fit_grid", "fit_rbf"),
    "._model": ("CORRECTION_METHODS", "MAX_FIT_PAIRS", "MAX_RBF_CENTRES", "AppliedCorrection",
                "Correction", "check_margin", "evaluate_correction", "fit_correction",
                "held_out_score_mm", "read_correction", "write_correction"),
    "._poly": ("POLY_ORDERS", "PolynomialCorrection", "axis_levels", "fit_polynomial",
               "monomial_exponents"),
    "._region": ("MAX_SHIFT_FLOOR_M", "STATUS", "FitBox", "check_over_box", "max_shift"),
    "._select": ("AUTO_METHODS", "fit_auto_correction"),
    "._workflow": ("ApplyOptions", "ApplyResult", "FitOptions", "FitResult",
                   "apply_correction_file", "fit_correction_files"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
