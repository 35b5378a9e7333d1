"""``openemt design carriers``: the crosstalk of a carrier plan measured in the raw-signal
simulator and demodulator, and a plan chosen for a stated level (docs/design.md#carriers).

Three leakages into a demodulated coupling, each measured by simulating raw samples
(:class:`openemt.signal.RawSimulator`, noise-free) and demodulating them with the plan
(:func:`openemt.signal.demodulate`), as a level in dB of the coupling it corrupts:

* ``crosstalk``: one coil coupled (coupling 1), the largest coupling demodulated at another
  coil's carrier;
* ``mains``: mains harmonics 1 to ``mains_harmonics`` of 1 V each, one at a time, with every
  coupling 1 V / sensor gain (so a level is demodulated volts per mains volt); the largest;
* ``intermod``: every coupling 1, the sensor samples passed through a weakly nonlinear front
  end ``v + a2 v^2 + a3 v^3`` whose second- and third-order terms are each ``distortion_db``
  below the full-scale signal (the sum of the carrier amplitudes): the largest change of a
  demodulated coupling. The simulator itself is linear; this front end is the stated model.

The plan chosen by :func:`carrier_plan` takes carriers on the frame's bins between the stated
frequencies, at least ``min_gap_bins`` apart, none within one bin of a second-order product
(sum, difference) or a second or third harmonic of the others, and none within reach of a
mains harmonic up to ``mains_harmonics`` (the window's spectrum at the distance at least
6 dB below the stated level): the lowest such set, found greedily. Avoiding every
third-order mix too is not possible for 8 carriers on 750 Hz bins up to bin 57 (a
backtracking search finds at most 5), so third-order mixes that land on carriers are counted
(``im3_collisions``) and their effect is what ``intermod_db`` measures.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from .._options import option
from .._result import Result

__all__ = ["CarrierOptions", "CarrierReport", "carrier_plan", "plan_leakage"]


@dataclass(frozen=True)
class CarrierOptions:
    """The options of :func:`carrier_plan`."""

    trackers: tuple[str, ...] = option((), "tracker files whose plans to report (default: every "
                                       "shipped tracker file)", positional=True, optional=True)
    sample_rate: float = option(96000.0, "ADC rate (samples/s)")
    output_rate: float = option(1500.0, "couplings per second")
    window: str = option("hann", "demodulation window", choices=("hann", "rect"))
    n_carriers: int = option(8, "carriers of the chosen plan")
    min_frequency: float = option(5000.0, "lowest carrier (Hz)")
    max_frequency: float = option(43000.0, "highest carrier (Hz)")
    min_gap_bins: int = option(2, "least spacing of two carriers, in frame bins")
    mains_frequency: float = option(50.0, "50 or 60 Hz")
    mains_harmonics: int = option(40, "mains harmonics considered (1 V each)")
    distortion_db: float = option(-100.0, "second- and third-order front-end distortion against "
                                  "full scale (dB)")
    max_level_db: float = option(-80.0, "the stated level every leakage of the chosen plan must "
                                 "stay below (dB)")


def _db(x: float) -> float:
    return float(20 * np.log10(max(float(x), 1e-300)))


def _layout(frequencies, sample_rate):
    from ..signal import ChannelLayout

    n = len(frequencies)
    return ChannelLayout(frequencies=tuple(frequencies), sample_rate=sample_rate,
                         sensor_channels=(0,), reference_channels=tuple(range(1, n + 1)))


def _run(layout, rate, window, C, *, mains=(), frames=24, front=None, seed=0):
    from ..signal import RawSignalConfig, RawSimulator, demodulate, frame_length
    from ._montecarlo import FixedCoupling

    hop, L = frame_length(layout, rate, window)
    cfg = RawSignalConfig(layout=layout, noise_rms=0.0, reference_noise_rms=0.0,
                          mains_amplitudes=tuple(mains))
    sim = RawSimulator(FixedCoupling(np.asarray(C, dtype=np.float64)), np.eye(4), cfg,
                       seed=seed, coupling_stride=hop)
    x = sim.read(L + (frames - 1) * hop)
    if front is not None:
        x[:, 0] = front(x[:, 0])
    return demodulate(x, layout, output_rate=rate, window=window).couplings


def plan_leakage(frequencies, sample_rate, output_rate, window, *, mains_frequency=50.0,
                 mains_harmonics=40, distortion_db=-100.0) -> dict:
    """Crosstalk, mains and intermodulation levels (dB) of a plan, measured in the simulator
    (see the module docstring); the worst of each and where it is."""
    lay = _layout(frequencies, sample_rate)
    n = len(frequencies)
    worst_x, where_x = 0.0, None
    for i in range(n):
        C = np.zeros((n, 1))
        C[i] = 1.0
        D = np.abs(_run(lay, output_rate, window, C))[:, :, 0]
        other = np.delete(D, i, axis=1).max()
        if other / D[:, i].min() > worst_x or where_x is None:
            worst_x = max(worst_x, other / D[:, i].min())
            where_x = int(i)
    worst_m, where_m = 0.0, None
    for h in range(1, int(mains_harmonics) + 1):
        if h * mains_frequency >= sample_rate / 2:
            break
        amps = [0.0] * (h - 1) + [1.0]
        cfg_mains = dict(mains=amps)
        D = np.abs(_run(lay, output_rate, window, np.zeros((n, 1)), frames=int(
            max(24, 3 * output_rate / mains_frequency)), **cfg_mains))
        if D.max() > worst_m or where_m is None:
            worst_m, where_m = max(worst_m, float(D.max())), h
    C = np.ones((n, 1))
    full = float(n)                      # the peak of the summed carriers (1 A, coupling 1)
    a = 10 ** (distortion_db / 20)
    lin = _run(lay, output_rate, window, C, seed=1)
    nl = _run(lay, output_rate, window, C, seed=1,
              front=lambda v: v + a * v ** 2 / full + a * v ** 3 / full ** 2)
    im = float(np.abs(nl - lin).max())
    return {"frequencies_hz": [float(f) for f in frequencies],
            "crosstalk_db": _db(worst_x), "crosstalk_source": where_x,
            "mains_db": _db(worst_m), "mains_harmonic": where_m,
            "intermod_db": _db(im),
            "im2_collisions": _collisions(frequencies, sample_rate, output_rate, window, 2),
            "im3_collisions": _collisions(frequencies, sample_rate, output_rate, window, 3)}


def _products(f, order: int = 3):
    """Products of the carriers ``f`` (Hz): the second and third harmonics and the
    second-order sums and differences; with ``order`` 3 also the third-order mixes of two and
    three carriers."""
    out = set()
    for a in f:
        out.update({2 * a, 3 * a})
    for a, b in itertools.permutations(f, 2):
        out.update({a + b, abs(a - b)} | ({2 * a + b, abs(2 * a - b)} if order >= 3 else set()))
    if order >= 3:
        for a, b, c in itertools.combinations(f, 3):
            out.update({a + b + c, abs(a + b - c), abs(a - b + c), abs(-a + b + c)})
    return out


def _collisions(frequencies, sample_rate, output_rate, window, order: int = 3) -> int:
    """Products (:func:`_products`) within one bin of a carrier."""
    from ..signal import frame_length

    _, L = frame_length(_layout(frequencies, sample_rate), output_rate, window)
    df = sample_rate / L
    f = list(frequencies)
    return int(sum(1 for p in _products(f, order) for c in f if abs(p - c) < 1.5 * df))


def _window_leak(window: str, L: int, df_hz, sample_rate: float) -> np.ndarray:
    """``|W(df)| / W(0)``: the demodulated amplitude of a unit sinusoid ``df_hz`` away from a
    carrier, relative to one on it (the window's spectrum)."""
    from ..signal import frame_window

    w = frame_window(window, L)
    n = np.arange(L)
    d = np.atleast_1d(np.asarray(df_hz, dtype=np.float64))
    W = np.abs(np.exp(-2j * np.pi * d[:, None] * n[None] / sample_rate) @ w)
    return W / w.sum()


def _choose(opts: CarrierOptions) -> list:
    from ..signal import frame_length

    hop = opts.sample_rate / opts.output_rate
    L = {"hann": 2, "rect": 1}[opts.window] * round(hop)
    frame_length(_layout([opts.sample_rate / L * 2], opts.sample_rate), opts.output_rate,
                 opts.window)
    df = opts.sample_rate / L
    lo = int(np.ceil(opts.min_frequency / df))
    hi = int(np.floor(min(opts.max_frequency, 0.45 * opts.sample_rate) / df))
    mains = opts.mains_frequency * np.arange(1, int(opts.mains_harmonics) + 1)
    chosen = []
    for k in range(lo, hi + 1):
        f = k * df
        # mains harmonics leak through the window's side lobes: keep 6 dB below the level
        if _window_leak(opts.window, L, mains - f, opts.sample_rate).max() >= \
                10 ** ((opts.max_level_db - 6.0) / 20):
            continue
        if chosen and k - round(chosen[-1] / df) < opts.min_gap_bins:
            continue
        trial = chosen + [f]
        if any(abs(p - c) < 1.5 * df for p in _products(trial, 2) for c in trial):
            continue
        chosen = trial
        if len(chosen) == opts.n_carriers:
            return chosen
    raise InputError(f"expected room for {opts.n_carriers} carriers between "
                     f"{opts.min_frequency:g} and {opts.max_frequency:g} Hz ({df:g} Hz bins, "
                     f"{opts.min_gap_bins} apart, clear of intermodulation and mains), got "
                     f"{len(chosen)}")


@dataclass(frozen=True, eq=False)
class CarrierReport(Result):
    """The result of :func:`carrier_plan` (``openemt design carriers --json``)."""

    sample_rate: float
    output_rate: float
    window: str
    max_level_db: float
    distortion_db: float
    mains: str
    existing: list
    chosen: dict
    chosen_below_level: bool

    def lines(self) -> list:
        """The human summary (``openemt design carriers`` on stderr)."""
        return [f"{e['tracker']}: crosstalk {e['crosstalk_db']:.0f} dB, mains "
                f"{e['mains_db']:.0f} dB, intermodulation {e['intermod_db']:.0f} dB"
                for e in self.existing] + [
            f"chosen {[round(f) for f in self.chosen['frequencies_hz']]} Hz: every level below "
            f"{self.max_level_db:g} dB: {self.chosen_below_level}"]


def carrier_plan(options: CarrierOptions | None = None, **overrides) -> CarrierReport:
    """Report the leakage of tracker files' carrier plans and choose a plan below
    ``max_level_db`` (see the module docstring)."""
    from dataclasses import replace

    from ..live import example_tracker, read_tracker

    opts = replace(options or CarrierOptions(), **overrides)
    if opts.n_carriers < 1 or opts.min_gap_bins < 1:
        raise InputError(f"expected a positive --n-carriers and --min-gap-bins, got "
                         f"{opts.n_carriers} and {opts.min_gap_bins}")
    paths = list(opts.trackers)
    if not paths:
        from pathlib import Path

        shipped = Path(example_tracker()).parent
        paths = [str(p) for p in sorted(shipped.glob("*.toml"))]
    existing = []
    for p in paths:
        spec = read_tracker(p)
        row = plan_leakage(spec.frequencies, spec.sample_rate, spec.output_rate, spec.window,
                           mains_frequency=opts.mains_frequency,
                           mains_harmonics=opts.mains_harmonics,
                           distortion_db=opts.distortion_db)
        existing.append({"tracker": str(p), "sample_rate": spec.sample_rate,
                         "output_rate": spec.output_rate, "window": spec.window, **row})
    f = _choose(opts)
    chosen = plan_leakage(f, opts.sample_rate, opts.output_rate, opts.window,
                          mains_frequency=opts.mains_frequency,
                          mains_harmonics=opts.mains_harmonics,
                          distortion_db=opts.distortion_db)
    below = all(chosen[k] < opts.max_level_db for k in ("crosstalk_db", "mains_db",
                                                         "intermod_db"))
    return CarrierReport(
        sample_rate=opts.sample_rate, output_rate=opts.output_rate, window=opts.window,
        max_level_db=opts.max_level_db, distortion_db=opts.distortion_db,
        mains=f"{opts.mains_frequency:g} Hz, harmonics 1-{opts.mains_harmonics} of 1 V each",
        existing=existing, chosen=chosen, chosen_below_level=bool(below))
