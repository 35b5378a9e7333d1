"""Cold start of the LM for a source whose coils are not concentric: a table of the
rotation-invariant couplings over positions.

With the sensor coils at one point (their offsets are far smaller than the source's), the
whitened couplings are ``C M_se^-1 = F(t)^T R``: row ``i`` of ``F(t)^T`` is the field of source
coil ``i`` at the sensor position ``t`` (the model's own dipole formula, evaluated with identity
sensor moments). The Gram matrix ``G = (C M_se^-1)(C M_se^-1)^T = F(t)^T F(t)`` does not depend
on the rotation: it is a function of the position alone, a 3-DOF fingerprint. For a concentric
source it is Kim18's ``k^2 (I + 3 u u^T)`` (docs/paper-procedure.md#kim18); with coil offsets of
a few centimetres at a few decimetres the coils see distances that differ by tens of percent,
which the concentric closed form reads as a different direction (its start is often on the
wrong side of the source, where the LM converges to a wrong local minimum or needs many
iterations and the sign-flip retries).

:class:`InvariantTable` tabulates the scale-free Gram matrix (its upper triangle over its trace)
and ``-log(trace) / 6`` (a log distance) at positions on a grid (directions of a Fibonacci
sphere x geometric distances) and finds the nearest table entries of a measured coupling
(k-d tree). Each candidate position gets its rotation from the orthogonal Procrustes problem
``min_R ||F(t)^T R - C M_se^-1||_F`` (determinant-corrected SVD); the candidate with the lowest
coupling residual under the full model is the start. Callers add the concentric closed form as
one more candidate, so the start is never worse, by this residual, than the closed form.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..field import DipoleModel
from ..field._dipole_kernel import dipole_eval, pack_model, unpack_model
from ..geometry import pose_from_rt
from ._linalg import det33, exp_so3, rotvec_from_matrix, svd3

__all__ = ["InvariantTable", "table_candidates", "table_for"]

# the tables of the last models used (one build costs about 1 s and 60 MB)
_TABLES: dict = {}
_KEEP = 2


def table_for(model: DipoleModel) -> InvariantTable:
    """The :class:`InvariantTable` of ``model`` with the default grid, built once per process
    for each of the last two models (keyed by the model's coils and gain)."""
    key = pack_model(model).tobytes()
    table = _TABLES.pop(key, None)
    if table is None:
        table = InvariantTable(model)
    _TABLES[key] = table    # most recent last
    while len(_TABLES) > _KEEP:
        del _TABLES[next(iter(_TABLES))]
    return table

_IU = np.triu_indices(3)


def _features(G):
    s = np.trace(G, axis1=1, axis2=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.hstack([G[:, _IU[0], _IU[1]] / s[:, None], (-np.log(s) / 6.0)[:, None]])


def _fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    ph = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.stack([z, r * np.cos(ph), r * np.sin(ph)], axis=1)


class InvariantTable:
    """Nearest-position lookup of rotation-invariant couplings for a 3x3 dipole model.

    ``directions`` grid directions over the whole sphere, distances from ``d_min`` to ``d_max``
    (m; default 10 times the largest source-coil offset, at least 0.5 m) with ratio ``ratio``.
    """

    def __init__(self, model: DipoleModel, *, directions: int = 6000, ratio: float = 1.03,
                 d_min: float = 0.03, d_max: float | None = None):
        from scipy.spatial import cKDTree

        self.model = model
        # rows of C_id(t) = F(t)^T: the source coils' fields at t (the model's own formula)
        self._field = model.replace(M_se=np.eye(3), L_se=np.zeros((3, 3)))
        self._W = np.linalg.inv(model.M_se)
        self._mdl = pack_model(model)
        self._fmdl = pack_model(self._field)
        offset = float(np.max(np.linalg.norm(model.L_so, axis=0)))
        if d_max is None:
            d_max = max(10.0 * offset, 0.5)
        dists = np.exp(np.arange(np.log(d_min), np.log(d_max), np.log(ratio)))
        self.positions = (dists[:, None, None]
                          * _fibonacci_sphere(directions)[None]).reshape(-1, 3)
        F = self._fields(self.positions)
        feats = _features(F @ np.swapaxes(F, 1, 2))
        good = np.all(np.isfinite(feats), axis=1)
        self.positions = self.positions[good]
        self._tree = cKDTree(feats[good])

    def _fields(self, t):
        return self._field.coupling(pose_from_rt(np.eye(3), t))

    def candidates(self, C, nvec, extra, k=4, away=None, far=16):
        """``(N, k + 1, 6)`` start pose vectors of real couplings ``C`` (N, 3, 3), ordered per
        sample by their coupling residual under the model (lowest first; a candidate that is
        not finite last): the ``k`` nearest table positions, each projected onto its sample's
        hemisphere ``t . n >= 0`` (``nvec`` (N, 3), zero rows for none), with their
        Procrustes rotations, and the pose vectors ``extra`` (N, 6).

        With positions ``away`` (N, 3): only table positions more than 20 % of ``|away|`` from
        ``away``, the first ``k`` of the ``far`` nearest (fewer: NaN candidates), to look for
        another minimum than one found at ``away``."""
        n = C.shape[0]
        # each sample divided by a power of two near its largest coupling: exact, and the
        # same features and candidates at any coupling scale
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            amax = np.max(np.abs(C.reshape(n, -1)), axis=1)
            f = np.ldexp(1.0, np.frexp(np.where(np.isfinite(amax) & (amax > 0), amax,
                                                1.0))[1])
            C = C / f[:, None, None]
            CW = C @ self._W
            feats = _features(CW @ np.swapaxes(CW, 1, 2))
            feats[:, -1] -= np.log(f) / 3.0
        ok = np.all(np.isfinite(feats), axis=1)
        feats[~ok] = 0.0
        # approximate nearest entries (within 1.5 times the nearest distance): a start
        q = k if away is None else far
        idx = self._tree.query(feats, k=q, eps=0.5)[1].reshape(n, q)
        tc = self.positions[idx]
        if away is not None:
            with np.errstate(invalid="ignore"):
                keep = (np.linalg.norm(tc - away[:, None], axis=2)
                        > 0.2 * np.linalg.norm(away, axis=1)[:, None])
            # the first k kept entries of each row, NaN where fewer
            order = np.argsort(~keep, axis=1, kind="stable")[:, :k]
            tc = np.take_along_axis(tc, order[:, :, None], axis=1)
            tc[~np.take_along_axis(keep, order, axis=1)] = np.nan
        tc[~ok] = np.nan
        out = np.empty((n, k + 1, 6))
        table_candidates(self._mdl, self._fmdl, f, np.ascontiguousarray(CW),
                         np.ascontiguousarray(C), np.ascontiguousarray(tc),
                         np.ascontiguousarray(nvec),
                         np.ascontiguousarray(extra, dtype=np.float64), out)
        return out


@njit(cache=True, nogil=True)
def table_candidates(mdl, fmdl, scale, CW, C, tc, nvec, extra, out):
    """For each sample ``s``: the candidate positions ``tc[s]`` (k, 3) projected onto the
    hemisphere ``nvec[s]``, their rotations ``argmin_R ||F(t)^T R - CW[s]||_F`` (``F(t)^T``:
    the packed field model ``fmdl`` at ``t``; determinant-corrected SVD), and the pose vector
    ``extra[s]``, written to ``out[s]`` (k + 1, 6) in the order of their residuals
    ``||C_model(pose) - C[s]||_F`` under the packed model ``mdl``. ``C`` and ``CW`` are the
    couplings divided by ``scale`` (N,), the models' gains are divided by it here."""
    k = tc.shape[1]
    eye = np.eye(3)
    Cp = np.empty((3, 3))
    d = np.empty((3, 3, 3))
    jac = (d, d, d, d)
    want = np.zeros(1, dtype=np.bool_)
    t = np.empty(3)
    R = np.empty((3, 3))
    B = np.empty((3, 3))
    rv = np.empty(3)
    res = np.empty(k + 1)
    tmp = np.empty(6)
    U = np.empty((3, 3))
    V = np.empty((3, 3))
    sv = np.empty(3)
    for s in range(C.shape[0]):
        geo = unpack_model(mdl, scale[s])
        fgeo = unpack_model(fmdl, scale[s])
        for j in range(k + 1):
            if j < k:
                dn = 0.0
                for a in range(3):
                    t[a] = tc[s, j, a]
                    dn += t[a] * nvec[s, a]
                if dn < 0.0:
                    for a in range(3):
                        t[a] -= dn * nvec[s, a]
                dipole_eval(fgeo, eye, t, Cp, jac, want[0])
                for a in range(3):
                    for b in range(3):
                        acc = 0.0
                        for i in range(3):
                            acc += Cp[i, a] * CW[s, i, b]
                        B[a, b] = acc
                finite = True
                for a in range(3):
                    for b in range(3):
                        finite = finite and np.isfinite(B[a, b])
                if finite:
                    svd3(B, U, sv, V)
                    if det33(U) * det33(V) < 0.0:
                        for a in range(3):
                            U[a, 2] = -U[a, 2]
                    for a in range(3):
                        for b in range(3):
                            R[a, b] = U[a, 0] * V[b, 0] + U[a, 1] * V[b, 1] + U[a, 2] * V[b, 2]
                    rotvec_from_matrix(R, rv)
                else:
                    rv[:] = np.nan
            else:
                for a in range(3):
                    t[a] = extra[s, a]
                    rv[a] = extra[s, 3 + a]
                exp_so3(rv, R)
            for a in range(3):
                out[s, j, a] = t[a]
                out[s, j, 3 + a] = rv[a]
            dipole_eval(geo, R, t, Cp, jac, want[0])
            ss = 0.0
            for a in range(3):
                for b in range(3):
                    r = Cp[a, b] - C[s, a, b]
                    ss += r * r
            res[j] = ss if np.isfinite(ss) and np.isfinite(rv[0]) else np.inf
        # insertion sort of the k + 1 candidates by residual (stable)
        for j in range(1, k + 1):
            rj = res[j]
            for a in range(6):
                tmp[a] = out[s, j, a]
            m = j
            while m > 0 and res[m - 1] > rj:
                res[m] = res[m - 1]
                for a in range(6):
                    out[s, m, a] = out[s, m - 1, a]
                m -= 1
            res[m] = rj
            for a in range(6):
                out[s, m, a] = tmp[a]
