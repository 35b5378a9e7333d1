"""Generated carrier-band inputs for the solver's band stage (``openemt bench fuzz``, section
``bands``).

Every case draws a band method (sometimes an unknown one), band frequencies (sometimes of the
wrong shape, zero, negative or non-finite), band couplings ``(N, n_bands, n_source,
n_sensor)`` (sometimes of the wrong shape; with non-finite, huge, tiny or zero entries on some
samples), a fusion time constant and rate, and a split of the samples into blocks. It holds
when the input is refused with one ``InputError`` line that says what was expected, or when the
couplings to solve have shape ``(N, n_source, n_sensor)``, are finite on every sample whose
bands are finite (``fuse``: from the first such sample on), and, streamed block by block with
the state carried, equal the whole stream's. Anything else is a finding.
"""

from __future__ import annotations

import random

import numpy as np

__all__ = ["fuzz_bands"]

_METHODS = ("fast", "slow", "fuse", "eddy-free")


def _case(rng: random.Random):
    method = rng.choice(_METHODS + ("mean",) if rng.random() < 0.05 else _METHODS)
    n, nb, nso, nse = rng.randint(0, 40), rng.choice((1, 2, 2, 3)), rng.randint(1, 4), \
        rng.randint(1, 4)
    f = np.array([[10 ** rng.uniform(1, 5) for _ in range(nso)] for _ in range(nb)])
    if rng.random() < 0.05:
        f[rng.randrange(nb), rng.randrange(nso)] = rng.choice((0.0, -5.0, np.nan, np.inf))
    if rng.random() < 0.03:
        f = f[:, :max(1, nso - 1)] if nso > 1 else f[None]
    nr = np.random.default_rng(rng.randrange(2**32))
    scale = 10 ** rng.uniform(-12, 6)
    B = scale * (nr.standard_normal((n, nb, nso, nse))
                 + 1j * rng.choice((0.0, 1e-4, 0.1)) * nr.standard_normal((n, nb, nso, nse)))
    for _ in range(rng.choice((0, 0, 1, 3))):
        if n:
            B[rng.randrange(n), rng.randrange(nb), rng.randrange(nso), rng.randrange(nse)] = \
                rng.choice((np.nan, np.inf, -np.inf, 0.0, 1e300))
    if rng.random() < 0.03:
        B = B[..., 0]
    tc = rng.choice((0.0, 10 ** rng.uniform(-4, 2), -1.0 if rng.random() < 0.05 else 0.1))
    rate = rng.choice((10 ** rng.uniform(-1, 4), np.nan if rng.random() < 0.05 else 150.0))
    cuts = sorted(rng.randint(0, n) for _ in range(rng.randint(0, 4)))
    return method, f, B, tc, rate, cuts


def _check(method, f, B, tc, rate, cuts) -> tuple[str, str]:
    from openemt.solve import BandStage

    stage = BandStage(method, f, time_constant=tc, rate=rate if method == "fuse" else None)
    whole, _ = stage(B)
    n = len(B)
    if whole.shape != (n,) + B.shape[2:]:
        return "garbage", f"shape {whole.shape} from {B.shape}"
    finite = np.isfinite(B.reshape(n, int(np.prod(B.shape[1:])))).all(axis=1)
    want = finite.copy()
    if method == "fuse" and finite.any():             # the fusion starts at a finite sample
        want[:int(np.argmax(finite))] = False
    elif method == "fuse":
        want[:] = False
    if not np.all(np.isfinite(whole.reshape(n, int(np.prod(whole.shape[1:])))).all(axis=1)[want]):
        with np.errstate(over="ignore", invalid="ignore"):
            huge = np.abs(B[finite]).max() if finite.any() else 0.0
        if huge < 1e150:                             # overflow of 1e300 entries is fair
            return "garbage", "non-finite couplings from finite bands"
    parts, state = [], None
    for a, b in zip([0] + cuts, cuts + [n]):
        C, state = stage(B[a:b], state)
        parts.append(C)
    streamed = np.concatenate(parts) if parts else whole
    ok = np.isfinite(whole) & np.isfinite(streamed)
    same_nan = np.array_equal(np.isfinite(whole), np.isfinite(streamed))
    scale = np.abs(whole[ok]).max() if ok.any() else 0.0
    if not same_nan or not np.allclose(streamed[ok], whole[ok], rtol=1e-9,
                                       atol=1e-9 * scale):
        return "garbage", "block-by-block result differs from the whole stream's"
    return "held", ""


def fuzz_bands(n: int, seed: int = 0, *, time_limit: float = 30.0, progress=None) -> dict:
    """Run ``n`` generated cases; the counts, findings and up to 20 examples."""
    from ._fuzzcases import run_checks

    def check(case):
        with np.errstate(all="ignore"):
            return _check(*case)

    def describe(case):
        m, f, B, tc, rate, cuts = case
        return {"case": f"{m} f{f.shape} B{B.shape} tc={tc} rate={rate} cuts={cuts}"}

    return run_checks(n, seed, _case, check, describe, time_limit=time_limit,
                      progress=progress)
