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
eddy currents for the slowly changing difference. Streamed block by block (the low-pass state
carried from one block to the next, ``state=``), it gives the batch result on the
concatenated stream.

The couplings to solve
----------------------
:class:`BandStage` is the one place where ``solve`` and ``track`` turn a sample's band
couplings into the real couplings the pose solver takes (``bands`` = :data:`BAND_METHODS`):
``fast`` (the highest band), ``slow`` (the lowest), ``fuse`` (above; rows in time order only),
``eddy-free`` (:func:`eddy_free_couplings` on the samples whose fast-band quadrature ratio
exceeds the distortion threshold, the fast band elsewhere) or ``sheet`` (``solve`` only, dipole
calibrations: on the samples whose fast or slow band's quadrature ratio exceeds the threshold,
the pose and a conducting sheet fitted together and the sheet's part taken out,
:func:`openemt.solve.fit_sheet`; ``eddy-free`` where no sheet explains a sample). ``auto``
(the default):
``fuse`` where the rows are a time series at a known rate (``track``, a recording), else
band 0 as without bands (docs/live.md#carrier-bands gives the reasons).
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError
from ._sheet import SHEET_SEARCHES

__all__ = ["BAND_METHODS", "DEFAULT_BAND_TIME_CONSTANT_S", "LIVE_BAND_METHODS", "BandReader",
           "BandStage", "band_dataset_shape", "cole_cole_couplings", "eddy_free_couplings",
           "fuse_bands", "resolve_bands"]

#: The choices of a live stream's ``bands`` (``track --bands``, the tracker file's ``[solve]
#: bands``).
LIVE_BAND_METHODS = ("auto", "fast", "slow", "fuse", "eddy-free")
#: The choices of ``bands`` (``solve --bands``): the live ones and ``sheet``.
BAND_METHODS = LIVE_BAND_METHODS + ("sheet",)
#: Default time constant (s) of the low-pass of ``fuse``: about 15 samples at the default
#: output rate; a slower one lags the eddy change of a moving sensor, a faster one passes more
#: of the slow band's noise.
DEFAULT_BAND_TIME_CONSTANT_S = 0.1


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
    >>> err(fast) > 8 * err(C0)
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
    # a sample whose values overflow here gets non-finite couplings, which the solvers flag
    # as invalid input: no warning for it
    with np.errstate(over="ignore", invalid="ignore"):
        d_re = Cf.real - Cs.real
        d_q = wf * Cf.imag - ws * Cs.imag
        num = np.sum(d_re * d_q, axis=(1, 2))
        den = np.sum(d_q * d_q, axis=(1, 2))
        tau = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
        # each entry its own time constant where its eddy signal is strong, shrunk towards the
        # sample's where it is weak (a ridge of weight `shrink` x the mean eddy signal)
        mu = float(shrink) * den[:, None, None] / d_q[0].size
        t_ij = (d_re * d_q + mu * tau[:, None, None]) / np.where(d_q**2 + mu > 0,
                                                                  d_q**2 + mu, 1.0)
        C0 = Cs.real - ws * t_ij * Cs.imag
    return (C0, tau) if return_tau else C0


def cole_cole_couplings(band_couplings, band_frequencies, *, taus=None, alphas=None,
                        return_params: bool = False):
    """The couplings extrapolated to zero frequency with a broadened relaxation per sample:
    ``(N, n_source, n_sensor)`` real (with ``return_params`` also ``tau`` and ``alpha`` per
    sample).

    Per entry ``C_b = C0 + k g(w_b)`` with a real strength ``k`` and the Cole-Cole form
    ``g(w) = (i w tau)^alpha / (1 + (i w tau)^alpha)`` shared by the sample's entries
    (``alpha = 1``: the single relaxation of :func:`eddy_free_couplings`). An infinite sheet
    responds with a spread of time constants (one per spatial wavenumber of the source field),
    which ``alpha < 1`` follows. Every band's in-phase and quadrature parts enter (two or more
    bands); for each ``(tau, alpha)`` of the grid (``taus``: default 120 values from 1 us to
    0.1 s; ``alphas``: default 0.3 to 1 in steps of 0.05) ``C0`` and ``k`` are linear least
    squares per entry, and the pair with the smallest residual over the sample's entries is
    kept. Same premises as :func:`eddy_free_couplings` (phase-calibrated couplings, no
    ferromagnetic object)."""
    C, f = _bands(band_couplings, band_frequencies)
    taus = np.logspace(-6, -1, 121) if taus is None else np.asarray(taus, dtype=np.float64)
    alphas = np.arange(0.3, 1.0001, 0.05) if alphas is None else \
        np.asarray(alphas, dtype=np.float64)
    n, nb, nso = C.shape[0], C.shape[1], C.shape[2]
    w = 2 * np.pi * f                                          # (nb, nso)
    y = np.concatenate([C.real, C.imag], axis=1)               # (N, 2 nb, nso, nse)
    best = np.full(n, np.inf)
    out = C[:, int(np.argmin(f.mean(axis=1)))].real.copy()
    t_best, a_best = np.zeros(n), np.ones(n)
    A = np.zeros((nso, 2 * nb, 2))
    A[:, :nb, 0] = 1.0
    for a in alphas:
        for t in taus:
            z = (1j * w * t) ** a
            g = z / (1 + z)                                    # (nb, nso)
            A[:, :nb, 1] = g.real.T
            A[:, nb:, 1] = g.imag.T
            x = np.einsum("iab,nbij->naij", np.linalg.pinv(A), y)
            r = y - np.einsum("iab,nbij->naij", A, x)
            ss = np.einsum("nbij,nbij->n", r, r)
            hit = ss < best
            if hit.any():
                best[hit] = ss[hit]
                out[hit] = x[hit, 0]
                t_best[hit], a_best[hit] = t, a
    return (out, t_best, a_best) if return_params else out


def fuse_bands(fast, slow, *, time_constant: float, rate: float, state=None,
               return_state: bool = False):
    """``fast + lowpass(slow - fast)`` along the first (time) axis: a causal first-order
    low-pass of time constant ``time_constant`` (s) at ``rate`` samples per second, started
    at the first difference. ``fast`` and ``slow`` are any arrays of equal shape (couplings
    ``(N, n_source, n_sensor)`` or pose vectors ``(N, 6)``).

    ``state``: the low-pass output of the sample before this block (None: a new stream);
    with ``return_state`` the result and the state after the block, so that a stream fused
    block by block equals the batch result on the concatenated stream. A sample whose
    difference is not finite leaves the state unchanged (its output: ``fast`` plus the last
    low-passed difference; NaN before the first finite one)."""
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
        return (a.copy(), state) if return_state else a.copy()
    if state is not None:
        state = np.asarray(state, dtype=np.float64)
        if state.shape != d.shape[1:]:
            raise InputError(f"expected a fusion state of shape {d.shape[1:]}, got "
                             f"{state.shape}")
    good = np.isfinite(d.reshape(len(d), -1)).all(axis=1)
    if len(d) <= 8 or not good.all():
        # a live read (a few samples, no filter set-up), or samples with a non-finite
        # difference: those leave the state as it is (their output: fast + the last
        # difference), so one bad sample does not end the fusion of the stream
        low = np.empty_like(d)
        y = state
        for k in range(len(d)):
            if good[k]:
                # lfilter's recursion below, term for term (alpha = 1: the difference itself;
                # y + alpha (d - y) overflowed where |d - y| exceeds the largest double, and
                # rounded differently: a stream cut into blocks gave another result)
                y = d[k] if y is None else alpha * d[k] + (1.0 - alpha) * y
            low[k] = np.nan if y is None else y
        out = a + low
        return (out, None if y is None else np.array(y)) if return_state else out
    from scipy.signal import lfilter

    zi = (1 - alpha) * (d[0] if state is None else state)
    low, _ = lfilter([alpha], [1.0, alpha - 1.0], d, axis=0,
                     zi=zi[None] if d.ndim > 1 else np.atleast_1d(zi))
    out = a + low
    return (out, low[-1].copy()) if return_state else out


def resolve_bands(method: str, n_bands: int, *, ordered: bool, rate=None,
                  where: str = "--bands") -> str | None:
    """The band method to use for couplings of ``n_bands`` carrier bands: ``method`` from
    :data:`BAND_METHODS` with ``auto`` resolved (``fuse`` for rows in time order at a known
    ``rate``, else None); None means band 0 as it is (one band, or ``auto`` on unordered
    rows). Refuses a method the data cannot serve, naming ``where``."""
    m = str(method).strip().lower()
    if m not in BAND_METHODS:
        raise InputError(f"expected a band method ({where}) in {', '.join(BAND_METHODS)}, got "
                         f"{method!r}")
    if n_bands < 2:
        if m in ("auto", "fast"):
            return None
        raise InputError(f"expected couplings of two or more carrier bands for {m} ({where}), "
                         f"got one band")
    if m == "auto":
        return "fuse" if ordered and rate else None
    if m == "fuse" and not ordered:
        raise InputError(f"expected rows in time order (a recording or a live stream) for "
                         f"fuse ({where}), got rows that are not a recording (use slow, fuse's "
                         f"steady state, or eddy-free)")
    if m == "fuse" and not rate:
        raise InputError(f"expected a known sample rate for fuse ({where}; the recording's "
                         f"meta sample_rate_hz), got none")
    return m


class BandStage:
    """The couplings to solve from a block of band couplings (module docstring).

    Parameters
    ----------
    method : str
        ``fast``, ``slow``, ``fuse``, ``eddy-free`` or ``sheet`` (resolved:
        :func:`resolve_bands`).
    frequencies : array (n_bands, n_source)
        The carriers (Hz) of the bands.
    time_constant, rate : float
        The low-pass of ``fuse`` (s) and the samples' rate (Hz).
    quadrature_threshold : float
        ``eddy-free``: the fast-band quadrature ratio above which a sample is corrected.
    signed : bool
        The ``solve`` command's reading of a dataset: ``fast`` and ``slow`` give the band's
        complex couplings as they are (the solver takes ``sign(Re z)|z|`` and normalises its
        residual by the complex norm, as for band 0 without bands) and ``fuse`` fuses
        ``sign(Re z)|z|``; else the in-phase part ``Re z`` throughout (the live pipeline's).
    model, hemisphere, sheet_searches :
        ``sheet``: the dipole calibration, the hemisphere of the pose that starts each
        sample's fit (the fast band solved as it is), and ``max_searches`` of
        :func:`openemt.solve.fit_sheet`.
    """

    def __init__(self, method: str, frequencies, *, time_constant: float =
                 DEFAULT_BAND_TIME_CONSTANT_S, rate: float | None = None,
                 quadrature_threshold: float = 1e-3, signed: bool = False, model=None,
                 hemisphere=None, sheet_searches: int = SHEET_SEARCHES):
        if method not in BAND_METHODS[1:]:
            raise InputError(f"expected a band method in {', '.join(BAND_METHODS[1:])}, got "
                             f"{method!r}")
        f = np.asarray(frequencies, dtype=np.float64)
        if f.ndim != 2 or len(f) < 2 or not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise InputError(f"expected band frequencies (n_bands >= 2, n_source), positive, "
                             f"got {f.tolist()}")
        tc = float(time_constant)
        if not (np.isfinite(tc) and tc >= 0):
            raise InputError(f"expected a band time constant >= 0 (s), got {time_constant!r}")
        if method == "fuse" and not (rate is not None and np.isfinite(rate) and rate > 0):
            raise InputError(f"expected a positive sample rate for band fusion, got {rate!r}")
        self.method, self.frequencies, self.time_constant = method, f, tc
        self.rate = None if rate is None else float(rate)
        self.quadrature_threshold = float(quadrature_threshold)
        self.signed = bool(signed)
        if method == "sheet":
            from ._sheet import check_sheet_model

            check_sheet_model(model)
        self.model, self.hemisphere = model, hemisphere
        self.sheet_searches = int(sheet_searches)
        self._solver = None
        #: ``sheet``: the fits of the last block (:class:`openemt.solve.SheetFit`, flagged
        #: samples only) and their rows in it
        self.last_sheet = None
        mean = f.mean(axis=1)
        self.fast, self.slow = int(np.argmax(mean)), int(np.argmin(mean))
        #: the band whose quadrature ratio flags a sample: the slow band where its couplings
        #: are what is solved (slow, fuse), else the fast band
        self.quadrature_band = self.slow if method in ("slow", "fuse") else self.fast

    def __getstate__(self):
        # a stage travels to cluster workers by pickle (BandReader): without its solver and
        # its last block's fits, which a worker makes again
        return {**self.__dict__, "_solver": None, "last_sheet": None}

    def _real(self, C):
        if not self.signed:
            return np.ascontiguousarray(C.real)
        from ..io import signed_real

        return signed_real(C)

    def __call__(self, bands, state=None):
        """``(couplings (N, n_source, n_sensor) real, state)`` of band couplings ``(N,
        n_bands, n_source, n_sensor)`` (complex); ``state`` is the stream's state after the
        previous block (None at its start; only ``fuse`` keeps one)."""
        B = np.asarray(bands)
        if B.ndim != 4 or B.shape[1] != len(self.frequencies) \
                or B.shape[2] != self.frequencies.shape[1]:
            raise InputError(f"expected band couplings (N, {len(self.frequencies)}, "
                             f"{self.frequencies.shape[1]}, n_sensor), got {B.shape}")
        m = self.method
        if m == "fast" or m == "slow":
            C = B[:, self.fast if m == "fast" else self.slow]
            return (C if self.signed else np.ascontiguousarray(C.real)), state
        if m == "fuse":
            return fuse_bands(self._real(B[:, self.fast]), self._real(B[:, self.slow]),
                              time_constant=self.time_constant, rate=self.rate, state=state,
                              return_state=True)
        from ..signal import distortion_ratio

        fast = B[:, self.fast]
        out = self._real(fast)
        hit = distortion_ratio(fast) > self.quadrature_threshold
        if m == "sheet":
            # a good conductor is nearly in phase at the fast band: its slow band's
            # quadrature flags it
            hit |= distortion_ratio(B[:, self.slow]) > self.quadrature_threshold
        if hit.any():
            out = out.copy()
            eddy = eddy_free_couplings(B[hit], self.frequencies, slow=self.slow, fast=self.fast)
            if m == "sheet":
                return self._sheet(B, out, hit, eddy, state)
            out[hit] = eddy
        return out, state

    def _sheet(self, B, out, hit, eddy, state):
        """``sheet`` on the flagged rows ``hit``: the fitted sheet's part taken out, the
        eddy-free couplings ``eddy`` where no sheet fits; ``state`` the last fitted sheet."""
        from ._sheet import fit_sheet

        if self._solver is None:
            from ._factory import prepare
            from ._hemisphere import DEFAULT_HEMISPHERE

            self._solver = prepare(self.model, hemisphere=self.hemisphere or
                                   DEFAULT_HEMISPHERE)
        solve = self._solver
        start = solve(np.ascontiguousarray(B[hit, self.fast].real)).poses
        fit, last = fit_sheet(self.model, B[hit], self.frequencies, start, fast=self.fast,
                              start=state, solve=lambda C: solve(C).poses,
                              max_searches=self.sheet_searches)
        rows = np.flatnonzero(hit)
        out[rows] = np.where(fit.fitted[:, None, None], fit.couplings, eddy)
        self.last_sheet = (fit, rows)
        return out, last


#: Where a dataset file keeps its band couplings: ``extra/couplings_bands`` as two parts
#: (complex) or as it is (real).
_BAND_PARTS = ("extra/couplings_bands_real", "extra/couplings_bands_imag")
_BAND_REAL = "extra/couplings_bands"


def band_dataset_shape(f) -> tuple | None:
    """The shape ``(N, n_bands, n_source, n_sensor)`` of the band couplings of an open
    dataset file ``f`` (h5py), or None where it has none."""
    d = f.get(_BAND_PARTS[0], f.get(_BAND_REAL))
    return tuple(d.shape) if d is not None and len(d.shape) == 4 else None


class BandReader:
    """Lazy row-block access to a dataset file's band couplings turned into the couplings to
    solve by a :class:`BandStage`: an array-like ``(N, n_source, n_sensor)`` float64 that
    :func:`openemt.solve.solve_to_file` slices block by block (here or on a cluster: it
    pickles by path).

    For ``fuse`` the low-pass state at every block start (multiples of ``block_rows``) is
    found by one pass over the file when the reader is made, so each block is computed on its
    own and the whole equals the batch fusion of the stream."""

    def __init__(self, path, stage: BandStage, block_rows: int):
        from pathlib import Path

        self.path, self.stage, self.rows = Path(path), stage, int(block_rows)
        self._file = None
        f = self._open()
        n, nb, nso, nse = band_dataset_shape(f)
        if nb != len(stage.frequencies):
            raise InputError(f"{self.path}: expected {len(stage.frequencies)} carrier bands "
                             f"(meta band_frequencies_hz), got {nb} in extra/couplings_bands")
        self.shape, self.ndim = (n, nso, nse), 3
        self.dtype = np.dtype(np.complex128 if stage.signed and stage.method in ("fast", "slow")
                              else np.float64)
        self._states: dict = {0: None}
        if stage.method == "fuse":
            state = None
            for a in range(0, n, self.rows):
                _, state = stage(self._raw(a, min(a + self.rows, n)), state)
                self._states[a + self.rows] = state

    def _open(self):
        if self._file is None:
            from ..io._h5safe import open_h5

            self._file = open_h5(self.path, "an openemt dataset HDF5 file")
            if band_dataset_shape(self._file) is None:
                self._file.close()
                self._file = None
                raise InputError(f"{self.path}: expected band couplings "
                                 f"(extra/couplings_bands), got none")
        return self._file

    def _raw(self, a: int, b: int) -> np.ndarray:
        f = self._open()
        if _BAND_PARTS[0] not in f:                # real band couplings: no quadrature
            return f[_BAND_REAL][a:b].astype(np.complex128)
        out = f[_BAND_PARTS[0]][a:b].astype(np.complex128)
        if _BAND_PARTS[1] in f:
            out.imag = f[_BAND_PARTS[1]][a:b]
        return out

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        if not isinstance(key, slice) or key.step not in (None, 1):
            raise InputError(f"expected a row slice of band couplings, got {key!r}")
        a, b, _ = key.indices(self.shape[0])
        if self.stage.method != "fuse":
            return self.stage(self._raw(a, b))[0]
        start = max(k for k in self._states if k <= a)
        state = self._states[start]
        if start < a:                       # a start off the block grid: run up to it
            state = self.stage(self._raw(start, a), state)[1]
        return self.stage(self._raw(a, b), state)[0]

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_file"] = None
        return d

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
