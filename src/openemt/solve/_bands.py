"""Several carrier bands per source coil: the eddy-current part taken out of each sample, and
the fusion of a fast band with a slow one (docs/simulator.md#carrier-bands).

Eddy-free couplings from two bands
----------------------------------
Near a conductor that is not ferromagnetic, the coupling at angular frequency ``w`` is the
clean (real, frequency-independent) coupling ``C0`` plus the eddy-current response. In the
low-induction limit every such response has the form of a relaxation: for one dominant time
constant ``tau`` (a thin sheet's ``mu0 sigma d / (2 lam)``, a ring's ``L / R``, the first
mode of a sphere), per coupling entry::

    C(w) = C0 + k  i w tau / (1 + i w tau)
    Re C(w) - C0 = k (w tau)^2 / (1 + (w tau)^2),   Im C(w) = k w tau / (1 + (w tau)^2)

so ``(Re C(w) - C0) / Im C(w) = w tau`` whatever the strength ``k`` (which differs from entry
to entry). With a slow band ``s`` and a fast band ``f`` of the same coil this is linear in
``C0`` and ``tau``::

    Re C_f - Re C_s = tau (w_f Im C_f - w_s Im C_s)
    C0 = Re C_s - w_s tau Im C_s

:func:`eddy_free_couplings` takes one ``tau`` per sample (least squares over its entries,
weighted by their eddy signal) and returns ``C0``: the coupling extrapolated to ``w -> 0``
without any calibration of the object. It needs signed, phase-calibrated couplings (the clean
coupling real). A ferromagnetic object breaks the premise (its static magnetisation is in
``C0`` and raises the in-phase part at low frequency); the quadrature still flags it.

Band fusion
-----------
:func:`fuse_bands` follows the fast band and corrects it from the slow one, as ILEMT does:
``fused = fast + lowpass(slow - fast)``; a first-order low-pass of time constant
``time_constant`` keeps the fast band's bandwidth for motion and the slow band's immunity to
eddy currents for the slowly changing difference.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError

__all__ = ["eddy_free_couplings", "fuse_bands"]


def _bands(C, f, n_source: int | None = None):
    C = np.asarray(C)
    if C.ndim != 4 or C.shape[1] < 2:
        raise InputError(f"expected band couplings of shape (N, n_bands >= 2, n_source, "
                         f"n_sensor), got {C.shape}")
    f = np.asarray(f, dtype=np.float64)
    if f.shape != C.shape[1:3] or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise InputError(f"expected band frequencies of shape {C.shape[1:3]} (n_bands, "
                         f"n_source), positive, got {f.shape}")
    return C, f


def eddy_free_couplings(band_couplings, band_frequencies, *, slow=None, fast=None,
                        shrink: float = 1.0, return_tau: bool = False):
    """The couplings extrapolated to zero frequency from a slow and a fast band (module
    docstring): ``(N, n_source, n_sensor)`` real, and with ``return_tau`` the time constant
    ``tau`` (s) per sample.

    ``band_couplings``: complex ``(N, n_bands, n_source, n_sensor)`` (a dataset's
    ``extra["couplings_bands"]``); ``band_frequencies``: ``(n_bands, n_source)`` (Hz).
    ``slow`` / ``fast``: band indices (default: the lowest and highest mean frequency).
    A sample without eddy signal (no quadrature) gets ``tau = 0``: its slow band as it is.
    Each entry uses its own time constant where its eddy signal is strong and the sample's
    where it is weak: ``tau_ij = (dRe dQ + mu tau) / (dQ^2 + mu)`` with ``mu = shrink`` x the
    mean ``dQ^2`` of the sample (``shrink`` large: one ``tau`` per sample, the most robust to
    noise; 1 by default).

    It works when the slow band is near the low-induction regime (``w_s tau`` of order 1 or
    less: stainless steel, titanium, small or thin parts); a large sheet of a good conductor
    (2 mm aluminium: ``tau`` about 5 ms) is inductive at both of ILEMT's bands and is not
    corrected (docs/simulator.md#carrier-bands gives the measured figures).

    Examples
    --------
    A 2 mm stainless-steel sheet under the simulated rig, seen at ILEMT's two bands:

    >>> import numpy as np
    >>> from openemt.simulate import simulate
    >>> from openemt.solve import eddy_free_couplings
    >>> bands = [[274.0, 334.0, 370.0], [7500.0, 10500.0, 13500.0]]
    >>> sheet = {"object": [{"kind": "sheet", "material": "stainless_steel",
    ...                      "position": [0.0, 0.244, -0.134], "thickness": 0.002}]}
    >>> clean = simulate("dipole-approx", "md", source_fixtures="YoutZup",
    ...                  sensor_fixtures="YoutZup", stage_sigma=0)
    >>> data = simulate("dipole-approx", "md", source_fixtures="YoutZup",
    ...                 sensor_fixtures="YoutZup", stage_sigma=0, metal=sheet, bands=bands)
    >>> C0 = eddy_free_couplings(data.extra["couplings_bands"], bands)
    >>> def err(C):
    ...     return float(np.abs(C - clean.couplings).max() / np.abs(clean.couplings).max())
    >>> fast = data.extra["couplings_bands"][:, 1].real
    >>> err(fast) > 20 * err(C0)
    True
    """
    C, f = _bands(band_couplings, band_frequencies)
    mean = f.mean(axis=1)
    s = int(np.argmin(mean)) if slow is None else int(slow)
    q = int(np.argmax(mean)) if fast is None else int(fast)
    if s == q or not (0 <= s < C.shape[1] and 0 <= q < C.shape[1]):
        raise InputError(f"expected two different band indices below {C.shape[1]}, got "
                         f"slow={s}, fast={q}")
    ws = 2 * np.pi * f[s][None, :, None]
    wf = 2 * np.pi * f[q][None, :, None]
    Cs, Cf = C[:, s], C[:, q]
    d_re = Cf.real - Cs.real
    d_q = wf * Cf.imag - ws * Cs.imag
    num = np.sum(d_re * d_q, axis=(1, 2))
    den = np.sum(d_q * d_q, axis=(1, 2))
    tau = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    # each entry its own time constant where its eddy signal is strong, shrunk towards the
    # sample's where it is weak (a ridge of weight `shrink` x the mean eddy signal)
    mu = float(shrink) * den[:, None, None] / d_q[0].size
    t_ij = (d_re * d_q + mu * tau[:, None, None]) / np.where(d_q**2 + mu > 0, d_q**2 + mu, 1.0)
    C0 = Cs.real - ws * t_ij * Cs.imag
    return (C0, tau) if return_tau else C0


def fuse_bands(fast, slow, *, time_constant: float, rate: float) -> np.ndarray:
    """``fast + lowpass(slow - fast)`` along the first (time) axis: a causal first-order
    low-pass of time constant ``time_constant`` (s) at ``rate`` samples per second, started
    at the first difference. ``fast`` and ``slow`` are any arrays of equal shape (couplings
    ``(N, n_source, n_sensor)`` or pose vectors ``(N, 6)``)."""
    a, b = np.asarray(fast, dtype=np.float64), np.asarray(slow, dtype=np.float64)
    if a.shape != b.shape or a.ndim < 1:
        raise InputError(f"expected fast and slow arrays of one shape, got {a.shape} and "
                         f"{b.shape}")
    tc, r = float(time_constant), float(rate)
    if not (np.isfinite(tc) and tc >= 0 and np.isfinite(r) and r > 0):
        raise InputError(f"expected time_constant >= 0 (s) and rate > 0 (Hz), got "
                         f"{time_constant!r} and {rate!r}")
    alpha = 1.0 - np.exp(-1.0 / (tc * r)) if tc > 0 else 1.0
    d = b - a
    if len(d) == 0:
        return a.copy()
    from scipy.signal import lfilter

    zi = (1 - alpha) * d[0]
    low, _ = lfilter([alpha], [1.0, alpha - 1.0], d, axis=0, zi=zi[None] if d.ndim > 1 else
                     np.atleast_1d(zi))
    return a + low
