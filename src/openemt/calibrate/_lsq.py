"""Least-squares fits of a calibration problem over a subset of its parameters."""

from __future__ import annotations

import numpy as np

__all__ = ["fit_free_parameters"]


def fit_free_parameters(prob, x0: np.ndarray, free: np.ndarray, *, tol: float, max_nfev):
    """Minimise ``prob.residuals`` over the parameters ``x0[free]`` (the others held at ``x0``)
    with scipy's Levenberg-Marquardt and the problem's analytic Jacobian.

    Returns ``(x, result)``: the full parameter vector at the solution and scipy's result.
    """
    from scipy.optimize import least_squares

    def full(xf):
        x = x0.copy()
        x[free] = xf
        return x

    res = least_squares(lambda xf: prob.residuals(full(xf)), x0[free],
                        jac=lambda xf: prob.residuals_and_jacobian(full(xf))[1][:, free],
                        method="lm", x_scale="jac", ftol=tol, xtol=tol, gtol=tol,
                        max_nfev=max_nfev)
    return full(res.x), res
