"""A conducting sheet's eddy currents taken out of each sample, from its carrier bands, with no
calibration of the object (``--bands sheet``).

Why
---
A good conductor (2 mm of aluminium: a table top, a tray, a shield) is in the inductive limit
at both of ILEMT's bands: its response is nearly the same at 274 Hz and at 7.5 kHz, so no
per-entry relaxation (:func:`openemt.solve.eddy_free_couplings`) can extrapolate it away
(docs/simulator.md#carrier-bands). Its *shape* can: an infinite thin sheet answers a source coil
with a known field, the mirror image of the coil receding into the sheet (Maxwell's receding
image), and that field has only four unknowns: the sheet's plane (a unit normal ``n`` and an
offset ``d``, the plane ``n . y + d = 0`` with the tracker on its ``+n`` side) and its
conductance ``S = sigma * thickness`` (siemens). With the sensor's pose that is 10 unknowns, and
a sample of two bands gives ``2 x 2 x n_source x n_sensor`` numbers (36 for 3 x 3 coils): each
sample is fitted on its own, pose and sheet together, and the sheet's part is subtracted.

The sheet's field
-----------------
A thin sheet reflects the transverse wavenumber ``lam`` of a source's field by
``R(lam) = -i a / (2 lam + i a)``, ``a = w mu0 S`` (the factor of
:func:`openemt.simulate.sheet_reflection` for thickness << skin depth). With ``R =
-b / (b + lam)``, ``b = i a / 2``, and the contour turned onto ``s = -i u``::

    B_sheet(r) = int_0^inf (a/2) exp(-a u / 2) B_image(r; depth + i u) du

where ``B_image(r; depth)`` is the field of the perfect conductor's image dipole (position
mirrored in the plane, moment ``m - 2 (m . n) n``), moved ``depth`` along ``-n`` - here a
complex depth, the dipole field continued analytically (``|r|^2 = r . r``, no singularity for
points above the sheet). The integral is a Gauss-Legendre rule of :data:`SHEET_NODES` nodes in
``log u`` over ``u a / 2`` in ``[1e-4, 40]`` and one of 4 nodes in ``u`` below. Independent of
the simulator's slab physics (a least-squares image series fitted to the full slab reflection
factor): the tests compare the two. Dipole models only (a source's image is a dipole).

The fit
-------
Per sample, Levenberg-Marquardt (``scipy.optimize.least_squares``) on the complex residual of
every band, relative to the fast band's coupling norm, from:

1. the previous sample's sheet (a stream: the sheet seldom moves), the pose under it found
   first from the fast band's own pose: straight (through a fixed point of the pose solver,
   where one is given), by continuation in the sheet's strength, or from the last fitted
   pose;
2. where that does not reach :data:`SHEET_GOOD_RESIDUAL`: a search over sheet normals (the
   6 axes and 8 diagonals of the source frame, the tracker on the ``+n`` side), offsets and
   conductances, stopping at the first start that does. After ``max_searches`` fruitless
   searches in a row (metal that is no sheet) only the warm starts are tried, until one
   fits.

A fit whose relative residual stays above :data:`SHEET_GOOD_RESIDUAL` is not a sheet (a
finite plate, a ring, a ferromagnetic object): that sample falls back to
:func:`eddy_free_couplings` and is counted (``SheetFit.fitted`` False). The couplings handed
to the pose solver are the fast band's in-phase part less the fitted sheet's in-phase part:
the measured sample, with the eddy part taken out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import InputError

__all__ = ["SHEET_GOOD_RESIDUAL", "SHEET_NODES", "SHEET_SEARCHES", "SheetFit", "fit_sheet",
           "sheet_couplings"]

#: Gauss-Legendre nodes of the receding-image integral (in log u).
SHEET_NODES = 40
#: Relative residual (complex, all bands, over the fast band's coupling norm) below which a
#: sample's sheet fit is taken; above it the sample is not explained by a sheet.
SHEET_GOOD_RESIDUAL = 5e-3
#: Fruitless searches for a sheet in a row before only warm starts are tried (``fit_sheet``'s
#: ``max_searches``, ``BandStage``'s ``sheet_searches``, ``bench metal --sheet-searches``).
SHEET_SEARCHES = 2
_MU0 = 4e-7 * np.pi
#: Strengths of the last sheet's part through which the pose is followed when it does not
#: converge straight from the fast band's pose (a continuation from the uncompensated pose).
_CONTINUATION = (0.2, 0.4, 0.6, 0.8, 1.0)
#: The search's sheet offsets (times the sensor's distance) and conductances (S).
_SEARCH_OFFSETS = (0.5, 1.2)
_SEARCH_CONDUCTANCES = (1e4,)
_gx, _gw = np.polynomial.legendre.leggauss(SHEET_NODES)
_Y0, _Y1 = np.log(1e-4), np.log(40.0)
_X = np.exp(0.5 * (_Y1 - _Y0) * (_gx + 1) + _Y0)                 # u a / 2 at the nodes
_W = 0.5 * (_Y1 - _Y0) * _gw * _X * np.exp(-_X)                   # weights, exp(-x) x dlog x
# below the rule's range, a 4-node Gauss-Legendre rule in u itself (where the image has not
# moved yet for a good conductor; a weak one's image has long receded there)
_lx, _lw = np.polynomial.legendre.leggauss(4)
_X = np.r_[0.5 * np.exp(_Y0) * (_lx + 1), _X]
_W = np.r_[0.5 * np.exp(_Y0) * _lw * np.exp(-_X[:4]), _W]


def _field(r, m):
    """Dipole field ``3 r (m . r) / |r|^5 - m / |r|^3`` of moments ``m`` at offsets ``r (...,
    3)`` (complex: continued analytically, ``|r|^2 = r . r``)."""
    r2 = np.einsum("...a,...a->...", r, r)
    ir2 = 1.0 / r2
    ir3 = ir2 / np.sqrt(r2)
    mr = np.einsum("...a,...a->...", m, r)
    return (3.0 * mr * ir2 * ir3)[..., None] * r - ir3[..., None] * m


def _normal(theta, phi):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def sheet_couplings(model, x, frequencies) -> tuple[np.ndarray, np.ndarray]:
    """``(clean, sheet)`` couplings of one sample: ``clean (n_source, n_sensor)`` (real) and
    the sheet's part ``(n_bands, n_source, n_sensor)`` (complex) for the parameters ``x = [x,
    y, z, rx, ry, rz, theta, phi, d, log S]`` (pose vector; the normal's polar angles in the
    source frame; offset (m); log conductance (S)) and carriers ``frequencies (n_bands,
    n_source)`` (Hz)."""
    from ..geometry import pose_from_vector

    x = np.asarray(x, dtype=np.float64)
    n = _normal(x[6], x[7])
    P = pose_from_vector(x[:6])
    clean = model.coupling(P[None])[0]
    R = P[:3, :3]
    pk = (R @ model.L_se).T + x[:3]                                  # sensor coils (n_se, 3)
    mk = (R @ model.M_se).T
    Ls, Ms = model.L_so.T, model.M_so.T                              # source coils (n_so, 3)
    Lm = Ls - 2.0 * (Ls @ n + x[8])[:, None] * n                     # mirrored positions
    Mm = Ms - 2.0 * (Ms @ n)[:, None] * n                            # the images' moments
    S = np.exp(x[9])
    f = np.asarray(frequencies, dtype=np.float64)
    a = 2.0 * np.pi * f * _MU0 * S                                    # (n_bands, n_so)
    u = (2.0 / a)[..., None] * _X                                     # (n_bands, n_so, Q)
    pos = Lm[None, :, None, :] + 1j * u[..., None] * n               # complex image depths
    r = pk[None, None, None] - pos[..., None, :]                      # (nb, n_so, Q, n_se, 3)
    Bf = _field(r, Mm[None, :, None, None, :])
    out = model.gain * np.einsum("q,bjqka,ka->bjk", _W, Bf, mk)
    return clean, out


def _fixed_point(model, sheet, C_fast, f_fast, pv, solve, steps: int = 6):
    """Pose vector from the fast band less the part of ``sheet`` at the current pose, solved
    ``steps`` times from ``pv`` (stops where the solver returns no finite pose)."""
    from ..geometry import vector_from_pose

    for _ in range(steps):
        _, part = sheet_couplings(model, np.r_[pv, sheet], f_fast[None])
        P = np.asarray(solve((C_fast.real - part[0].real)[None]))[0]
        if not np.all(np.isfinite(P)):
            break
        pv = vector_from_pose(P)
    return pv


@dataclass(frozen=True)
class SheetFit:
    """The per-sample sheet fits of :func:`fit_sheet` (``N`` samples)."""

    #: the couplings to solve ``(N, n_source, n_sensor)``: the fast band's in-phase part less
    #: the fitted sheet's (as it is where no sheet fits; :class:`BandStage` puts the
    #: eddy-free couplings there)
    couplings: np.ndarray
    #: the fitted poses ``(N, 4, 4)`` (NaN where no sheet fits)
    poses: np.ndarray
    #: the sheet's plane ``n . y + d = 0`` in the source frame, the source coils on its ``+n``
    #: side: unit normal ``n (N, 3)``, offset ``d (N,)`` (m); its conductance ``(N,)`` (S)
    normal: np.ndarray
    offset: np.ndarray
    conductance: np.ndarray
    #: the fit's relative residual ``(N,)`` (all bands, over the fast band's coupling norm)
    relative_residual: np.ndarray
    #: whether the sample's fit explains it (relative residual below the threshold)
    fitted: np.ndarray
    #: least-squares starts tried per sample
    starts: np.ndarray


def _search_starts(p):
    """Sheet starts ``(theta, phi, d, log S)`` for a sensor at ``p``: 14 normals (axes and
    diagonals) with the sensor on the ``+n`` side, 2 offsets, 1 conductance."""
    dirs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    dirs += [(a, b, c) for a in (1, -1) for b in (1, -1) for c in (1, -1)]
    r = max(float(np.linalg.norm(p)), 1e-3)
    out = []
    for v in dirs:
        n = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
        th, ph = float(np.arccos(n[2])), float(np.arctan2(n[1], n[0]))
        for k in _SEARCH_OFFSETS:
            d = k * r
            if n @ p + d <= 0.05 * r:                 # the sensor behind or on that plane
                continue
            for S in _SEARCH_CONDUCTANCES:
                out.append(np.array([th, ph, d, np.log(S)]))
    return out


def check_sheet_model(model):
    """``model`` if the sheet fit can take it (a dipole model: a source coil's image in a
    sheet is a dipole), else an InputError naming what arrived."""
    if getattr(model, "kind", None) != "dipole":
        raise InputError(f"expected a dipole calibration for --bands sheet (a source coil's "
                         f"image in a sheet is a dipole), got a {type(model).__name__}")
    return model


def fit_sheet(model, bands, frequencies, initial, *, fast: int = 0,
              good: float = SHEET_GOOD_RESIDUAL, start=None, solve=None,
              max_searches: int = SHEET_SEARCHES, max_nfev: int = 200):
    """Fit each sample's pose and sheet (module docstring).

    Parameters
    ----------
    model : DipoleModel
        The clean calibration.
    bands : array (N, n_bands, n_source, n_sensor), complex
        Phase-calibrated band couplings.
    frequencies : array (n_bands, n_source)
        The bands' carriers (Hz).
    initial : array (N, 4, 4)
        Start poses (the fast band solved as it is); a non-finite one starts from the
        previous sample's fitted pose.
    fast : int
        The fast band's index (whose couplings are corrected).
    start : array (4,) or None
        The sheet ``(theta, phi, d, log S)`` to try first (a stream's last fit).
    solve : callable or None
        Real couplings ``(n, n_source, n_sensor)`` -> poses ``(n, 4, 4)`` (the clean pose
        solver): with it, the pose start under the last sheet is refined by solving the fast
        band less that sheet's part, a few times over.
    max_searches : int
        Searches over sheet starts in a row that may fail before the search stops (a found
        sheet allows them again): near metal that is no sheet, every sample would search.

    Returns ``(SheetFit, last)``: ``last`` the sheet of the last fitted sample (None where
    none fitted), the ``start`` of the next block.
    """
    from scipy.optimize import least_squares

    from ..geometry import pose_from_vector, vector_from_pose

    check_sheet_model(model)
    B = np.asarray(bands)
    f = np.asarray(frequencies, dtype=np.float64)
    if B.ndim != 4 or B.shape[1] != len(f) or B.shape[2:] != (model.n_source, model.n_sensor):
        raise InputError(f"expected band couplings (N, {len(f)}, {model.n_source}, "
                         f"{model.n_sensor}), got {B.shape}")
    P0 = np.asarray(initial, dtype=np.float64)
    n = len(B)
    x_out = np.full((n, 10), np.nan)
    res = np.full(n, np.inf)
    tried = np.zeros(n, dtype=np.int64)
    last = None if start is None else np.asarray(start, dtype=np.float64)
    prev_pose = None
    searches = int(max_searches)

    def resid(x, C, scale, lam=1.0):
        clean, sheet = sheet_couplings(model, x, f)
        d = (clean[None] + lam * sheet - C) / scale
        return np.concatenate([d.real.ravel(), d.imag.ravel()])

    def resid_pose(v, sheet, C, scale, lam):
        return resid(np.r_[v, sheet], C, scale, lam)

    with np.errstate(all="ignore"):      # a far start's overflow: a bad residual
        for i in range(n):
            C = B[i]
            scale = float(np.linalg.norm(C[fast]))
            if not (np.isfinite(scale) and scale > 0 and np.all(np.isfinite(C))):
                continue
            if np.all(np.isfinite(P0[i])):
                pv = vector_from_pose(P0[i])
            elif prev_pose is not None:
                pv = prev_pose
            else:
                continue
            # (sheet start, how the pose under it is found): the last sheet held (the pose
            # straight, by continuation in the sheet's strength, or the last fitted pose), then
            # the search (the pose straight)
            starts = [] if last is None else [(last, None), (last, _CONTINUATION)]
            if last is not None and prev_pose is not None:
                starts.append((last, "previous"))
            if searches > 0:
                starts += [(s, ()) for s in _search_starts(pv[:3])]
            tried_warm = sum(1 for _, st in starts if st != ())
            best_x, best = None, np.inf
            for s, steps in starts:
                tried[i] += 1
                try:
                    if steps == "previous":          # the last fitted sample's pose
                        x0 = np.r_[prev_pose, s]
                    else:
                        # the pose under the sheet start first: straight (from the fast band's
                        # pose, or the fixed point) or followed through the sheet's strength
                        q = pv
                        if steps is None and solve is not None:
                            q = _fixed_point(model, s, C[fast], f[fast], pv, solve)
                        for lam in steps or (1.0,):
                            q = least_squares(resid_pose, q, args=(s, C, scale, lam),
                                              method="lm", max_nfev=max_nfev // 4).x
                        x0 = np.r_[q, s]
                    r = least_squares(resid, x0, args=(C, scale), method="lm",
                                      max_nfev=max_nfev)
                except (ValueError, FloatingPointError):
                    continue
                v = float(np.sqrt(2.0 * r.cost))
                if np.isfinite(v) and v < best:
                    best_x, best = r.x, v
                if best < good:
                    break
            searched = searches > 0 and len(starts) > tried_warm
            if best < good:
                searches = max_searches
            elif searched:
                searches -= 1
            if best_x is None:
                continue
            x_out[i], res[i] = best_x, best
            if best < good:
                last = best_x[6:].copy()
                prev_pose = best_x[:6].copy()
    ok = res < good
    out = np.ascontiguousarray(B[:, fast].real).copy()
    normal = np.full((n, 3), np.nan)
    offset = np.full(n, np.nan)
    centre = model.L_so.mean(axis=1)
    for i in np.flatnonzero(ok):
        _, sheet = sheet_couplings(model, x_out[i], f[fast:fast + 1])
        out[i] = B[i, fast].real - sheet[0].real
        nrm, d = _normal(x_out[i, 6], x_out[i, 7]), x_out[i, 8]
        sign = 1.0 if nrm @ centre + d >= 0 else -1.0    # the same plane, sources on +n
        normal[i], offset[i] = sign * nrm, sign * d
    poses = np.full((n, 4, 4), np.nan)
    if ok.any():
        poses[ok] = pose_from_vector(x_out[ok, :6])
    fit = SheetFit(couplings=out, poses=poses, normal=normal,
                   offset=offset,
                   conductance=np.where(ok, np.exp(x_out[:, 9]), np.nan),
                   relative_residual=res, fitted=ok, starts=tried)
    return fit, last
