"""``openemt design optimize``: change a board's coils, or a rig source's, to lower a
statistic of the position bound over a volume (docs/design.md#optimize).

A board: each coil's centre in the board plane and angle about its normal, and with
``vary="all"`` its size and turns; the coil count, shape, trace and layers are the start's.
Drive power at a common current is ``sum_i I^2 R_i`` with ``R_i = rho L_i / (w t)`` (``L_i``
the trace length); a coil's turns are the most quarter turns whose resistance is within its
share of the start board's (the shares are variables), so the total never exceeds the
start's. Constraints, as penalties added to the objective: every coil's outline inside the
start board's footprint (the bounding rectangle of its coils' outlines), and any two coils'
outlines at least ``min_spacing_mm`` apart (each square outline grown by half the spacing,
separated by the separating-axis test). A rig source (dipole model): see ``_rig``.

The objective is the median, 95th percentile or maximum of the position bound over the
(point, orientation) pairs of the map, for the noise of the start layout's map (fixed, so a
layout is judged at the start's noise floor and its own field strength). The search is
scipy's Powell method from the start layout and from ``starts - 1`` perturbed copies of it,
within ``max_evaluations`` objective evaluations in all.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .._errors import InputError
from .._options import option
from .._result import Result
from ._map import MapOptions, _scaled, bound_map, map_of, map_summary
from ._orient import orientation_set
from ._search import _Search
from ._targets import resolve_target

__all__ = ["OptimizeOptions", "OptimizedLayout", "optimize_layout"]

_STATISTICS = ("median", "p95", "max")


@dataclass(frozen=True)
class OptimizeOptions(MapOptions):
    """The options of :func:`optimize_layout`: a map's, and the search's."""

    statistic: str = option("p95", "statistic of the position bound to minimise",
                            choices=_STATISTICS)
    min_spacing_mm: float = option(2.0, "least gap between two coils' outlines (mm)")
    max_evaluations: int = option(3000, "objective evaluations of the search in all")
    starts: int = option(1, "searches: from the start layout and from perturbed copies of it")
    vary: str = option("placement", "board coils: centres and angles (placement), or also sizes "
                       "and turns (all) within the start's drive power",
                       choices=("placement", "all"))
    min_size_mm: float = option(20.0, "least coil size (outer side or diameter, mm) with --vary "
                                "all")
    offset_mm: float = option(20.0, "rig sources: each coil's position within +- this of its "
                              "start (mm)")
    output: str | None = option(None, "write the optimised board file here (.toml, or .json; a "
                                "rig: a calibration .json): every command that takes one reads it",
                                flag=("-o", "--output"))
    html: str | None = option(None, "write a self-contained HTML page with both maps here")


def _corners(centers, angles, half):
    """Corners ``(n, 4, 2)`` of square outlines of half side ``half`` (n,)."""
    c, s = np.cos(angles), np.sin(angles)
    loc = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)
    ex = np.stack([c, s], -1)
    ey = np.stack([-s, c], -1)
    return centers[:, None, :] + half[:, None, None] * (
        loc[None, :, :1] * ex[:, None, :] + loc[None, :, 1:] * ey[:, None, :])


def _overlap(corners) -> float:
    """Sum over pairs of the separating-axis penetration depth of convex quadrilaterals."""
    n = len(corners)
    total = 0.0
    edges = np.roll(corners, -1, axis=1) - corners
    normals = np.stack([-edges[..., 1], edges[..., 0]], -1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    for i in range(n):
        for j in range(i + 1, n):
            axes = np.concatenate([normals[i, :2], normals[j, :2]])
            pi = corners[i] @ axes.T
            pj = corners[j] @ axes.T
            depth = np.minimum(pi.max(0) - pj.min(0), pj.max(0) - pi.min(0))
            total += max(0.0, float(depth.min()))
    return total


#: Copper of the stated drive-power model: resistivity (ohm m, 20 C) and trace thickness
#: (m, 1 oz). Only the ratio to the start board's power is a constraint; these set the
#: reported watts.
COPPER_RESISTIVITY = 1.68e-8
COPPER_THICKNESS = 35e-6


def trace_length(coil) -> float:
    """Length (m) of a coil's current path (its trace, the via and the return lead)."""
    return float(np.linalg.norm(np.diff(coil.local_path(), axis=0), axis=1).sum())


def coil_resistance(coil) -> float:
    """``rho L / (w t)``: the trace's resistance (ohm) in the stated copper."""
    return COPPER_RESISTIVITY * trace_length(coil) / (coil.trace_width * COPPER_THICKNESS)


class _Layout(_Search):
    """The map of a board layout from the search's vector ``[x_i, y_i, angle_i, size_i,
    share_i]`` per coil: centre, angle, size (the outer side or diameter) and share of the
    drive-power budget. A coil's turns per layer are the most quarter turns whose trace
    resistance is within its share of the start board's summed resistance (and that fit
    the size with a hole of one pitch), so the total drive power at a common current never
    exceeds the start's."""

    N = 5

    def __init__(self, board, points, rotations, sigma, statistic, spacing):
        from ..board import BoardModel

        super().__init__(points, rotations, sigma, statistic)
        self.board = board
        normals = np.stack([c.normal for c in board.coils])
        if not np.allclose(normals, [0.0, 0.0, 1.0]):
            raise InputError("expected a planar board whose coils face +z to optimise, got "
                             "other coil normals")
        shapes = {c.shape for c in board.coils}
        if shapes - {"square_spiral", "circular"}:
            raise InputError(f"expected square or circular coils to optimise, got {shapes}")
        self.spacing = spacing
        self.budget = sum(coil_resistance(c) for c in board.coils)
        x0 = self.vector(board)
        v = x0.reshape(-1, self.N)
        corners = _corners(v[:, :2], v[:, 2], v[:, 3] / 2)
        self.lo = corners.reshape(-1, 2).min(0)
        self.hi = corners.reshape(-1, 2).max(0)
        self.model_of = lambda b: BoardModel.from_board(b)
        self._cache = {}
        self._turns = {}
        self.basis = None
        model = self.model_of(board)
        if model.dof == 5:
            # translation, and the two rotation directions normal to the sensor axis
            axis = self.poses[:, :3, :3] @ board.sensor.coil_axes()[0]
            e = np.eye(3)[np.argmin(np.abs(axis), axis=1)]
            b1 = np.cross(axis, e)
            b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
            b2 = np.cross(axis, b1)
            B = np.zeros((len(axis), 6, 5))
            B[:, :3, :3] = np.eye(3)
            B[:, 3:, 3] = b1
            B[:, 3:, 4] = b2
            self.basis = B

    def vector(self, board) -> np.ndarray:
        return np.array([[c.center[0], c.center[1], c.angle, c.outer_size[0],
                          coil_resistance(c) / self.budget] for c in board.coils]).ravel()

    def _sized(self, i, size, share):
        """Coil ``i`` of the start board at outer size ``size`` with the most quarter turns
        per layer whose resistance is within ``share`` of the budget (None: not one)."""
        c = self.board.coils[i]
        key = (i, float(size), float(share))
        if key in self._turns:
            return self._turns[key]
        sizes = tuple(float(s) * size / c.outer_size[0] for s in c.outer_size)
        fit = (min(sizes) / 2 - c.trace_width / 2 - c.pitch) / c.pitch
        limit = share * self.budget * (1 + 1e-9)

        def at(k):
            return replace(c, outer_size=sizes, turns_per_layer=k / 4)

        lo, hi = 0, int(np.floor(4 * fit + 1e-9))
        while lo < hi:              # the resistance grows with the turns: bisect
            mid = (lo + hi + 1) // 2
            if coil_resistance(at(mid)) <= limit:
                lo = mid
            else:
                hi = mid - 1
        out = at(lo) if lo >= 1 else None
        if len(self._turns) > 65536:
            self._turns.clear()
        self._turns[key] = out
        return out

    def board_of(self, x, *, strict=False):
        """The board of vector ``x``; a coil whose share allows no quarter turn keeps one
        (and :meth:`penalty` counts it) unless ``strict``."""
        v = np.asarray(x).reshape(-1, self.N)
        shares = np.maximum(v[:, 4], 0.0)
        shares = shares / max(shares.sum(), 1e-300)
        coils = []
        for i, c in enumerate(self.board.coils):
            s = self._sized(i, v[i, 3], shares[i])
            if s is None:
                if strict:
                    return None
                s = replace(c, outer_size=tuple(float(z) * v[i, 3] / c.outer_size[0]
                                                for z in c.outer_size), turns_per_layer=0.25)
            coils.append(replace(s, center=np.array([v[i, 0], v[i, 1], c.center[2]]),
                                 angle=float(v[i, 2])))
        return replace(self.board, coils=tuple(coils))

    def power_ratio(self, board) -> float:
        """Drive power at a common current over the start board's: ``sum R_i / sum R_i0``."""
        return sum(coil_resistance(c) for c in board.coils) / self.budget

    def penalty(self, x) -> float:
        b = self.board_of(x)
        v = np.asarray(x).reshape(-1, self.N)
        half = np.array([c.outer_size[0] / 2 for c in b.coils])
        c = _corners(v[:, :2], v[:, 2], half + self.spacing / 2)
        # the outline itself inside the footprint (circular coils: the square that holds them)
        inner = _corners(v[:, :2], v[:, 2], half)
        out = np.maximum(self.lo - inner.reshape(-1, 2), 0).sum() + \
            np.maximum(inner.reshape(-1, 2) - self.hi, 0).sum()
        # drive power above the budget (a coil kept at a quarter turn its share does not
        # allow): 1 % over weighs as 1 mm of overlap
        power = 0.1 * max(0.0, self.power_ratio(b) - 1.0 - 1e-9)
        return float(_overlap(c) + out + power)

    def _coil_fisher(self, i, coil) -> np.ndarray:
        """``J_i^T J_i`` ``(N, 6, 6)`` of coil ``i`` alone (cached by its placement, size and
        turns): the Fisher information is a sum over the source coils, and a search step
        mostly changes one coil."""
        key = (i, float(coil.center[0]), float(coil.center[1]), float(coil.angle),
               float(coil.outer_size[0]), float(coil.turns_per_layer))
        F = self._cache.get(key)
        if F is None:
            jac = self.model_of(replace(self.board, coils=(coil,))).jacobians(
                self.poses, params=False)
            n = len(self.poses)
            J = np.concatenate([jac.d_translation.reshape(n, -1, 3),
                                jac.d_rotation.reshape(n, -1, 3)], axis=-1)
            F = np.swapaxes(J, 1, 2) @ J
            if len(self._cache) > 4096:
                self._cache.clear()
            self._cache[key] = F
        return F

    def position_std(self, x) -> np.ndarray:
        """The position bound at every (point, orientation) of layout ``x`` (m), from the
        summed per-coil Fisher information (the same bound as :func:`bound_map`)."""
        b = self.board_of(x)
        F = sum(self._coil_fisher(i, c) for i, c in enumerate(b.coils))
        if self.basis is not None:
            F = np.swapaxes(self.basis, 1, 2) @ F @ self.basis
        F = F / self.sigma ** 2
        with np.errstate(all="ignore"):
            ok = np.linalg.cond(F) < 1e14
        out = np.full(len(F), np.inf)
        if np.any(ok):
            cov = np.linalg.inv(F[ok])
            out[ok] = np.sqrt(np.trace(cov[:, :3, :3], axis1=1, axis2=2))
        return out


@dataclass(frozen=True, eq=False)
class OptimizedLayout(Result):
    """The result of :func:`optimize_layout` (``openemt design optimize --json``)."""

    target: str
    statistic: str
    volume: dict
    orientations: str
    noise_sigma: float
    constraints: str
    evaluations: int
    seconds: float
    start: dict
    optimized: dict
    improvement_p95: float
    improvement_statistic: float
    montecarlo_improvement_p95: float | None
    montecarlo_bound_improvement_p95: float | None
    coils: list
    power: dict
    output: str | None
    html: str | None
    bounds: object = None
    start_bounds: object = None
    board: object = None
    start_board: object = None
    calibration: object = None
    _not_in_dict = ("bounds", "start_bounds", "board", "start_board", "calibration")

    def lines(self) -> list:
        """The human summary (``openemt design optimize`` on stderr)."""
        a, b = self.start["position_mm"]["p95"], self.optimized["position_mm"]["p95"]
        return [f"{self.target}: p95 position bound {a:.4f} -> {b:.4f} mm "
                f"({100 * self.improvement_p95:.1f} % lower)"]


def _map_block(bm, mc, target_mm) -> dict:
    return {"position_mm": _scaled(map_summary(bm.position_std, target_mm * 1e-3), 1e3),
            "rotation_deg": _scaled(map_summary(bm.rotation_std), float(np.degrees(1.0))),
            "montecarlo": mc}


def _board_search(target, opts, start_map, rotations, sigma):
    """(search, best vector, optimised board) of a board target."""
    lay = _Layout(target.board, start_map.points, rotations, sigma, opts.statistic,
                  opts.min_spacing_mm * 1e-3)
    x0 = lay.vector(target.board)
    if lay.penalty(x0) > 0:
        raise InputError(f"expected a start layout within its footprint and "
                         f"{opts.min_spacing_mm:g} mm spacing, got coils closer than that")
    v0 = x0.reshape(-1, lay.N)
    n = len(v0)
    # centres in units of 10 mm, angles of 0.1 rad within a quarter turn of the start (a
    # square's angles repeat every quarter), sizes of 10 mm, power shares of 1 / (4 n)
    scale = np.tile([0.01, 0.01, 0.1, 0.01, 0.25 / n], n)
    size_lo = opts.min_size_mm * 1e-3 if opts.vary == "all" else v0[:, 3]
    size_hi = float(min(lay.hi - lay.lo)) if opts.vary == "all" else v0[:, 3]
    if opts.vary == "all" and not 0 < opts.min_size_mm * 1e-3 <= v0[:, 3].min():
        raise InputError(f"expected 0 < --min-size-mm <= the start's smallest coil "
                         f"({v0[:, 3].min() * 1e3:g} mm), got {opts.min_size_mm:g}")
    half_lo = np.broadcast_to(size_lo, (n,)) / 2
    lo = np.column_stack([lay.lo[0] + half_lo, lay.lo[1] + half_lo, v0[:, 2] - np.pi / 4,
                          np.broadcast_to(size_lo, (n,)), np.full(n, 0.0)]).ravel()
    hi = np.column_stack([lay.hi[0] - half_lo, lay.hi[1] - half_lo, v0[:, 2] + np.pi / 4,
                          np.broadcast_to(size_hi, (n,)), np.full(n, 1.0)]).ravel()
    free = np.tile([True, True, True, opts.vary == "all", opts.vary == "all"], n)
    best = lay.search(x0, scale, lo, hi, free, opts,
                      jitter=np.tile([0.01, 0.01, 0.2, 0.0, 0.0], n))
    board = replace(lay.board_of(best), name=f"{target.board.name}-optimized",
                    description=f"{target.board.name} with coil "
                    f"{'centres and angles' if opts.vary == 'placement' else 'centres, angles, sizes and turns'}"
                    f" optimised for the {opts.statistic} position bound (openemt design "
                    f"optimize)")
    return lay, board


def _power(start, opt, model) -> dict:
    return {"model": model, "start": start, "optimized": opt, "ratio": opt / start}


def optimize_layout(options: OptimizeOptions | None = None, **overrides) -> OptimizedLayout:
    """Optimise a board's coils (centres and angles; with ``vary="all"`` also sizes and
    turns) or a rig source's coils (positions and moments); see the module docstring.

    Examples
    --------
    >>> from openemt.design import optimize_layout
    >>> r = optimize_layout(target="anser", grid=(3, 3, 2), orientations="down",
    ...                     max_evaluations=20, starts=1, montecarlo=0)
    >>> r.optimized["position_mm"]["p95"] <= r.start["position_mm"]["p95"]
    True
    """
    from ._montecarlo import montecarlo

    opts = replace(options or OptimizeOptions(), **overrides)
    if opts.statistic not in _STATISTICS:
        raise InputError(f"expected --statistic in {list(_STATISTICS)}, got {opts.statistic!r}")
    if opts.vary not in ("placement", "all"):
        raise InputError(f"expected --vary placement or all, got {opts.vary!r}")
    if opts.max_evaluations < 1 or opts.starts < 1:
        raise InputError(f"expected a positive --max-evaluations and --starts, got "
                         f"{opts.max_evaluations} and {opts.starts}")
    if not opts.min_spacing_mm >= 0:
        raise InputError(f"expected --min-spacing-mm >= 0, got {opts.min_spacing_mm}")
    if not opts.offset_mm >= 0:
        raise InputError(f"expected --offset-mm >= 0, got {opts.offset_mm}")
    target = resolve_target(opts.target)
    rig = target.board is None and getattr(target.model, "kind", "") == "dipole"
    if target.board is None and not rig:
        raise InputError(f"expected a board (a built-in board, a board file or a board "
                         f"calibration) or a dipole rig source (a rig preset or a dipole "
                         f"calibration) to optimise, got {target.kind} {opts.target!r}")
    if rig and opts.output and not str(opts.output).lower().endswith(".json"):
        raise InputError(f"expected a .json output for a rig source (a calibration file), "
                         f"got {opts.output!r}")
    start_map, volume, sigma, _ = map_of(target, opts)
    rotations = orientation_set(opts.orientations, opts.n_orientations)
    t0 = time.perf_counter()
    board = cal = None
    if rig:
        from ._rig import _RigLayout

        lay = _RigLayout(target.model, start_map.points, rotations, sigma, opts.statistic,
                         opts.offset_mm * 1e-3)
        x0, scale, lo, hi = lay.bounds()
        best = lay.search(x0, scale, lo, hi, np.ones(x0.size, bool), opts,
                          jitter=0.5 * scale)
        model = lay.model_of(best)
        m0 = target.model
        power = _power(lay.power, float(np.sum(model.M_so ** 2)),
                       "sum |m_i|^2 (the same windings: each coil's drive power I^2 R is "
                       "proportional to its moment squared), held at the start's")
        coils = [{"name": f"source{i + 1}", "position": model.L_so[:, i].tolist(),
                  "offset": (model.L_so[:, i] - m0.L_so[:, i]).tolist(),
                  "moment": model.M_so[:, i].tolist(),
                  "axis": (model.M_so[:, i] / np.linalg.norm(model.M_so[:, i])).tolist(),
                  "moment_ratio": float(np.linalg.norm(model.M_so[:, i])
                                        / np.linalg.norm(m0.M_so[:, i]))}
                 for i in range(model.n_source)]
        constraints = (f"{model.n_source} source coils of the start (same windings), each "
                       f"within +-{opts.offset_mm:g} mm of its start position per axis, "
                       f"any axis, total drive power (sum |m_i|^2) the start's; the sensor "
                       f"the start's")
        from ..io import Calibration

        base = target.calibration if target.calibration is not None else Calibration(m0)
        cal = replace(base, model=model, mode="design", stats={}, standard_errors={},
                      provenance={**base.provenance,
                                  "generator": "openemt.design.optimize_layout",
                                  "optimized_from": str(opts.target)})
    else:
        lay, board = _board_search(target, opts, start_map, rotations, sigma)
        model = lay.model_of(board)
        w = [coil_resistance(c) for c in target.board.coils]
        w1 = [coil_resistance(c) for c in board.coils]
        power = _power(float(sum(w)), float(sum(w1)),
                       f"sum_i I^2 R_i at I = 1 A (the couplings' current), R_i = rho L_i / "
                       f"(w t): L_i the coil's trace length, w its trace width, copper rho = "
                       f"{COPPER_RESISTIVITY:g} ohm m, t = {COPPER_THICKNESS * 1e6:g} um; "
                       f"W per A^2; held at most the start's")
        coils = [{"name": c.name, "center": c.center.tolist(), "angle": float(c.angle),
                  "outer_size": float(c.outer_size[0]), "turns_per_layer": c.turns_per_layer,
                  "trace_length": trace_length(c), "resistance": coil_resistance(c)}
                 for c in board.coils]
        constraints = (f"{len(board.coils)} coils of the start board ("
                       + ("same shape, size, turns" if opts.vary == "placement" else
                          f"same shape, trace width and spacing, layers; sizes "
                          f"{opts.min_size_mm:g} mm to the footprint, turns per layer in "
                          f"quarter turns that fit the size")
                       + f"), drive power at a common current at most the start's, planar, "
                       f"inside the start footprint x "
                       f"{[round(float(v) * 1e3, 2) for v in (lay.lo[0], lay.hi[0])]} mm, y "
                       f"{[round(float(v) * 1e3, 2) for v in (lay.lo[1], lay.hi[1])]} mm, "
                       f"outlines at least {opts.min_spacing_mm:g} mm apart")
    seconds = time.perf_counter() - t0
    opt_map = bound_map(model, start_map.points, rotations, sigma)
    from ._map import montecarlo_plan

    plan = montecarlo_plan(target, opts)
    mc_start = montecarlo(target.model, start_map, sigma, n_points=opts.montecarlo,
                          trials=opts.trials, seed=opts.seed, plan=plan,
                          start=opts.montecarlo_start)
    mc_opt = montecarlo(model, opt_map, sigma, trials=opts.trials,
                        seed=opts.seed + 1, pick=mc_start.get("indices"), plan=plan,
                        start=opts.montecarlo_start)
    s0 = lay.stat(start_map.position_std)
    s1 = lay.stat(opt_map.position_std)
    p0 = float(np.percentile(start_map.position_std, 95))
    p1 = float(np.percentile(opt_map.position_std, 95))
    mc_gain = mc_bound_gain = None
    if mc_start and mc_opt:
        # the same (point, orientation) pairs in both layouts: the 95th percentile over them
        # of the Monte Carlo RMS error, and of the bound (what the Monte Carlo should show)
        def p95_of(mc, key):
            return np.percentile([p[key] for p in mc["points"]], 95)

        mc_gain = float(1 - p95_of(mc_opt, "montecarlo_rms_mm")
                        / p95_of(mc_start, "montecarlo_rms_mm"))
        mc_bound_gain = float(1 - p95_of(mc_opt, "bound_mm") / p95_of(mc_start, "bound_mm"))
    if opts.output and rig:
        from ..io import write_calibration

        write_calibration(cal, opts.output)
    elif opts.output:
        from ..io import write_board

        write_board(board, opts.output)
    result = OptimizedLayout(
        target=str(opts.target), statistic=opts.statistic, volume=volume.to_dict(),
        orientations=opts.orientations, noise_sigma=sigma, constraints=constraints,
        evaluations=lay.evaluations, seconds=seconds,
        start=_map_block(start_map, mc_start, opts.target_mm),
        optimized=_map_block(opt_map, mc_opt, opts.target_mm),
        improvement_p95=float(1 - p1 / p0), improvement_statistic=float(1 - s1 / s0),
        montecarlo_improvement_p95=mc_gain, montecarlo_bound_improvement_p95=mc_bound_gain,
        coils=coils, power=power, output=opts.output, html=opts.html, bounds=opt_map,
        start_bounds=start_map, board=board, start_board=target.board, calibration=cal)
    if opts.html:
        from ._html import optimize_document

        optimize_document(result).write(opts.html)
    return result
