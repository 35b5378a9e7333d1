"""Output correction on pose pairs (measured, reference): DLT, polynomials, lookup tables."""

from ._dlt import DltFit, apply_linear_correction, fit_dlt, linear_correction_rms

__all__ = [
    "DltFit",
    "apply_linear_correction",
    "fit_dlt",
    "linear_correction_rms",
]
