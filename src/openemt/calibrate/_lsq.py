"""Least-squares fits of a calibration problem over a subset of its parameters."""

from __future__ import annotations

import numpy as np

__all__ = ["fit_free_parameters"]


#: Rows per block of the Gram matrix in :func:`_compressed`: small enough products that a
#: threaded BLAS runs them on one thread (on the loaded machine one 3834 x 73 product cost
#: 28 ms of CPU on threads, the blocks 1.5 ms).
_GRAM_BLOCK_ROWS = 48


def _compressed(r: np.ndarray, J: np.ndarray, free: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """An upper triangular ``R`` with ``R^T R = A^T A`` for ``A = [J[:, free] r]``: residuals
    ``R[:, n]`` and Jacobian ``R[:, :n]``, ``n + 1`` rows each, with the same norm, column
    norms, ``J^T J``, ``J^T r`` and ``|r + J p|`` for every step ``p`` as ``r`` and ``J`` (an
    orthogonal transform of both; the last residual is the part of ``r`` outside the range of
    ``J``). The Cholesky factor of the Gram matrix, accumulated over blocks of rows, with the
    columns scaled to unit norm; a Householder QR where it is not positive definite."""
    m, n = J.shape[0], np.size(free)
    nb = -(-m // _GRAM_BLOCK_ROWS)
    A = np.zeros((nb * _GRAM_BLOCK_ROWS, n + 1))
    A[:m, :n] = J[:, free]
    A[:m, n] = r
    A3 = A.reshape(nb, _GRAM_BLOCK_ROWS, n + 1)
    G = np.matmul(A3.transpose(0, 2, 1), A3).sum(axis=0)
    s = np.sqrt(np.diag(G))
    s[s == 0.0] = 1.0
    try:
        R = _upper_cholesky(G / np.outer(s, s)) * s
    except np.linalg.LinAlgError:
        R = np.linalg.qr(A[:m], mode="r")
    return R[:, n].copy(), R[:, :n].copy()


def _upper_cholesky(A):
    """The upper Cholesky factor ``R`` (``R^T R = A``): numpy's own where it has one (numpy >= 2),
    else the lower factor transposed (numpy 1.26, the declared minimum)."""
    try:
        return np.linalg.cholesky(A, upper=True)
    except TypeError:
        return np.linalg.cholesky(A).T


def fit_free_parameters(prob, x0: np.ndarray, free: np.ndarray, *, tol: float, max_nfev,
                        compress: bool = False):
    """Minimise ``prob.residuals`` over the parameters ``x0[free]`` (the others held at ``x0``)
    with scipy's Levenberg-Marquardt and the problem's analytic Jacobian.

    With ``compress``, MINPACK is handed the triangular factor of ``[J r]`` at each point
    instead of the tall residual vector and Jacobian (:func:`_compressed`; one
    ``residuals_and_jacobian`` per point, no residual-only evaluations): every quantity the
    Levenberg-Marquardt iteration uses (``|r|``, ``J^T J``, ``J^T r``, the column norms of
    ``x_scale="jac"`` and the predicted reduction ``|r + J p|``) is the same, so are its steps
    (up to rounding), while its QR costs ``n`` rather than ``m`` rows. ``result.fun`` is then
    the compressed residual vector (same norm and cost).

    Returns ``(x, result)``: the full parameter vector at the solution and scipy's result.
    """
    from scipy.optimize import least_squares

    def full(xf):
        x = x0.copy()
        x[free] = xf
        return x

    opts = dict(method="lm", x_scale="jac", ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev)
    n = np.size(free)
    if compress:
        r0, J0 = prob.residuals_and_jacobian(x0)
        compress = r0.size > 2 * (n + 1)
    if not compress:
        res = least_squares(lambda xf: prob.residuals(full(xf)), x0[free],
                            jac=lambda xf: prob.residuals_and_jacobian(full(xf))[1][:, free],
                            **opts)
        return full(res.x), res

    last = {"x": x0[free].copy(), "rJ": _compressed(r0, J0, free)}

    def evaluate(xf):
        if not np.array_equal(xf, last["x"]):
            r, J = prob.residuals_and_jacobian(full(xf))
            last["x"], last["rJ"] = np.array(xf, copy=True), _compressed(r, J, free)
        return last["rJ"]

    res = least_squares(lambda xf: evaluate(xf)[0], x0[free], jac=lambda xf: evaluate(xf)[1],
                        **opts)
    return full(res.x), res
