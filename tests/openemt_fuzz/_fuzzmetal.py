"""Generated metal scenes (``openemt bench fuzz``, section ``metal``).

Every case is a scene table drawn at random (kinds, named or given materials from an insulator
to 1e12 S/m and mu_r up to 1e6, sizes from 1 um to 10 m, any pose, every motion, with some
values made wrong: negative, zero, non-finite, of the wrong type or shape, unknown keys) and
evaluated on a few sensor poses at carriers from 1 Hz to 1 MHz. It holds when the scene is
refused with one ``InputError`` line that says what was expected, or when its couplings are
finite, complex and of shape ``(N, n_source, n_sensor)``. Anything else (another exception,
a non-finite coupling, a vague message) is a finding.
"""

from __future__ import annotations

import math
import random

import numpy as np

__all__ = ["fuzz_metal"]

_MATERIALS = ("aluminium", "copper", "stainless steel", "carbon_steel", "titanium", "ferrite")
_BAD = (-1.0, 0.0, float("nan"), float("inf"), "x", [1.0], None)


def _num(rng: random.Random, lo: float, hi: float) -> float:
    return 10 ** rng.uniform(math.log10(lo), math.log10(hi))


def _maybe_bad(rng: random.Random, value, p: float = 0.05):
    return rng.choice(_BAD) if rng.random() < p else value


def _object(rng: random.Random) -> dict:
    kind = rng.choice(("sphere", "disk", "plate", "sheet", "ring", "cube"
                       if rng.random() < 0.02 else "sphere"))
    if rng.random() < 0.7:
        mat = rng.choice(_MATERIALS)
    else:
        mat = {"conductivity": _maybe_bad(rng, rng.choice((0.0, _num(rng, 1e-3, 1e12)))),
               "mu_r": _maybe_bad(rng, rng.choice((1.0, _num(rng, 1.0, 1e6))))}
    d = {"kind": kind, "material": mat,
         "position": _maybe_bad(rng, [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5),
                                      rng.uniform(-0.6, -0.05) if kind == "sheet"
                                      else rng.uniform(-0.5, 0.5)]),
         "rotation": _maybe_bad(rng, [0.0, 0.0, 0.0] if kind == "sheet"
                                else [rng.uniform(-3, 3) for _ in range(3)])}
    size = _num(rng, 1e-6, 10.0)
    if kind in ("sphere", "disk", "ring"):
        d["radius"] = _maybe_bad(rng, size)
    if kind in ("disk", "plate", "sheet"):
        d["thickness"] = _maybe_bad(rng, rng.choice((_num(rng, 1e-6, 0.1), "inf"))
                                    if kind == "sheet" else _num(rng, 1e-6, 0.1))
    if kind == "plate":
        d["size"] = _maybe_bad(rng, [size, _num(rng, 1e-6, 10.0)])
    if kind == "ring":
        d["wire_radius"] = _maybe_bad(rng, size * rng.uniform(0.001, 1.2))
    if kind in ("disk", "plate") and rng.random() < 0.3:
        d["filaments"] = _maybe_bad(rng, rng.randint(0, 70))
    if rng.random() < 0.3:
        m = rng.choice(("fixed", "linear", "periodic", "waypoints", "teleport"))
        motion = {"kind": m}
        if m == "linear":
            motion["velocity"] = [rng.uniform(-1, 1) for _ in range(3)]
        elif m == "periodic":
            motion.update(amplitude=[rng.uniform(-1, 1) for _ in range(3)],
                          period_s=_maybe_bad(rng, _num(rng, 1e-3, 1e3)))
        elif m == "waypoints":
            k = rng.randint(0, 4)
            motion.update(times=sorted(rng.uniform(0, 10) for _ in range(k)),
                          positions=[[rng.uniform(-0.2, 0.2) for _ in range(3)]
                                     for _ in range(k)])
        d["motion"] = motion
    if rng.random() < 0.02:
        d["colour"] = "red"
    return d


def fuzz_metal(n: int, seed: int = 0, *, time_limit: float = 30.0, progress=None) -> dict:
    """Run ``n`` generated scenes; the counts, findings and up to 20 examples."""
    from openemt.field import DipoleModel
    from openemt.geometry import pose_from_vector
    from openemt.simulate import MetalScene

    from ._fuzzcases import run_checks

    model = DipoleModel.concentric()

    def make(rng):
        table = {"object": [_object(rng) for _ in range(rng.randint(0, 3))]}
        vec = np.array([[rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3),
                         rng.uniform(0.05, 0.4)] + [rng.uniform(-3, 3) for _ in range(3)]
                        for _ in range(4)])
        return table, vec, [_num(rng, 1.0, 1e6) for _ in range(3)]

    def check(case):
        table, vec, freqs = case
        scene = MetalScene.from_dict(table)
        dC = scene.induced_couplings(model, pose_from_vector(vec), freqs,
                                     t=np.linspace(0, 5, 4))
        if dC.shape != (4, 3, 3) or not np.all(np.isfinite(dC)):
            return "garbage", f"shape {dC.shape}, finite {np.isfinite(dC).all()}"
        return "held", ""

    return run_checks(n, seed, make, check, lambda case: {"scene": repr(case[0])[:300]},
                      time_limit=time_limit, progress=progress)
