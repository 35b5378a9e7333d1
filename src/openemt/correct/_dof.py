"""How many pose pairs a correction method needs (docs/correction.md#how-many-pairs).

Each pair gives one equation per corrected coordinate (x, y, z, and the three rotation
components when orientation is corrected). A method with ``p`` free parameters per
coordinate is exactly determined by ``p`` pairs and then fits the noise exactly; its held-out
error is only trustworthy with several times more. :func:`pair_requirements` gives ``p``
and the recommended minimum ``MIN_PAIRS_FACTOR * p``; :func:`openemt.correct.fit_correction`
warns below it.

==========  ==============================================  ===================
method      parameters per coordinate ``p``                  recommended minimum
==========  ==============================================  ===================
``none``    0                                               0
``dlt``     5 (15 free entries of the 4x4 over 3 coords)    15
``poly``    monomials of the chosen order: 4, 10, 20, 35,   12 at order 1,
            56 for orders 1-5 (fewer on level-sampled axes)  3 x terms otherwise
``grid``    grid nodes (2x2x2 = 8 at least)                 3 x nodes (24+)
``rbf``     4 (the linear part; the spline part is set by    12
            the smoothing chosen held out)
==========  ==============================================  ===================

``bernstein`` has ``(D + 1)^3`` parameters per coordinate at degree D per axis (8, 27, 64, 125,
216, 343 for D = 1-6) and the same recommended minimum of 3 x terms.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_PAIRS_FACTOR", "pair_requirements"]

#: Recommended pairs per parameter per coordinate.
MIN_PAIRS_FACTOR = 3


def _poly_terms(order, max_power) -> int:
    from ._poly import monomial_exponents

    return len(monomial_exponents(int(order), max_power))


def pair_requirements(method: str, params: dict) -> dict:
    """``{"parameters_per_coordinate": p, "min_pairs": MIN_PAIRS_FACTOR * p}`` of a fit."""
    if method == "none":
        p = 0
    elif method == "dlt":
        p = 5
    elif method == "poly":
        mp = params.get("max_power")
        mp = None if mp is None else tuple(mp)
        orders = [params.get("pos_order")] + ([params["rot_order"]]
                                              if params.get("rot_order") is not None else [])
        p = max(_poly_terms(o, mp) for o in orders)
    elif method == "grid":
        p = int(np.prod(params["shape"]))
    elif method == "rbf":
        p = 4
    elif method == "bernstein":
        p = max((int(d) + 1) ** 3 for d in (params.get("pos_degree"), params.get("rot_degree"))
                if d is not None)
    else:  # pragma: no cover - methods are validated before
        raise KeyError(method)
    return {"parameters_per_coordinate": int(p), "min_pairs": int(MIN_PAIRS_FACTOR * p)}
