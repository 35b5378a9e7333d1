"""``openemt design optimize``: move a board's coils to lower a statistic of the position
bound over a volume (docs/design.md#optimize).

The unknowns are each coil's centre in the board plane and its angle about its normal; the
coils themselves (shape, size, turns, layers) and their drive current are the start board's,
so the coil count and the total drive stay the start's by construction. Constraints, as
penalties added to the objective: every coil's outline inside the start board's footprint (the
bounding rectangle of its coils' outlines), and any two coils' outlines at least
``min_spacing_mm`` apart (each square outline grown by half the spacing, separated by the
separating-axis test). The objective is the median, 95th percentile or maximum of the position
bound over the (point, orientation) pairs of the map, for the noise of the start layout's map
(fixed, so a layout cannot win by its field strength's effect on an SNR). The search is
scipy's Powell method from the start layout and from ``starts - 1`` perturbed copies of it,
within ``max_evaluations`` objective evaluations in all.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .._errors import InputError
from .._result import Result
from ._map import MapOptions, _scaled, bound_map, map_of, map_summary
from ._orient import map_poses, orientation_set
from ._targets import resolve_target

__all__ = ["OptimizeOptions", "OptimizedLayout", "optimize_layout"]

_STATISTICS = ("median", "p95", "max")
#: The search's smooth stand-in for a statistic: the mean above this percentile.
SMOOTH_PERCENTILE = {"p95": 90.0, "max": 98.0}


@dataclass(frozen=True)
class OptimizeOptions(MapOptions):
    """The options of :func:`optimize_layout`: a map's, and the search's."""

    statistic: str = field(default="p95", metadata={
        "choices": _STATISTICS, "help": "statistic of the position bound to minimise"})
    min_spacing_mm: float = field(default=2.0, metadata={
        "help": "least gap between two coils' outlines (mm)"})
    max_evaluations: int = field(default=3000, metadata={
        "help": "objective evaluations of the search in all"})
    starts: int = field(default=1, metadata={
        "help": "searches: from the start layout and from perturbed copies of it"})
    output: str | None = field(default=None, metadata={
        "flag": ("-o", "--output"), "help": "write the optimised board file here (.toml, or "
        ".json): every command that takes a board reads it"})
    html: str | None = field(default=None, metadata={
        "help": "write a self-contained HTML page with both maps here"})


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


class _Layout:
    """The map of a board layout from the search's vector ``[x_i, y_i, angle_i]``."""

    def __init__(self, board, points, rotations, sigma, statistic, spacing):
        from ..board import BoardModel

        self.board = board
        self.points, self.rotations, self.sigma = points, rotations, sigma
        self.statistic = statistic
        normals = np.stack([c.normal for c in board.coils])
        if not np.allclose(normals, [0.0, 0.0, 1.0]):
            raise InputError("expected a planar board whose coils face +z to optimise, got "
                             "other coil normals")
        shapes = {c.shape for c in board.coils}
        if shapes - {"square_spiral", "circular"}:
            raise InputError(f"expected square or circular coils to optimise, got {shapes}")
        self.spacing = spacing
        self.half = np.array([c.outer_size[0] / 2 for c in board.coils]) + spacing / 2
        x0 = self.vector(board)
        corners = _corners(x0.reshape(-1, 3)[:, :2], x0.reshape(-1, 3)[:, 2],
                           self.half - spacing / 2)
        self.lo = corners.reshape(-1, 2).min(0)
        self.hi = corners.reshape(-1, 2).max(0)
        self.model_of = lambda b: BoardModel.from_board(b)
        self.evaluations = 0
        self.best = (None, np.inf)
        self._cache = {}
        self.poses = map_poses(points, rotations)
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

    @staticmethod
    def vector(board) -> np.ndarray:
        return np.array([[c.center[0], c.center[1], c.angle] for c in board.coils]).ravel()

    def board_of(self, x):
        v = np.asarray(x).reshape(-1, 3)
        coils = tuple(replace(c, center=np.array([v[i, 0], v[i, 1], c.center[2]]),
                              angle=float(v[i, 2])) for i, c in enumerate(self.board.coils))
        return replace(self.board, coils=coils)

    def penalty(self, x) -> float:
        v = np.asarray(x).reshape(-1, 3)
        c = _corners(v[:, :2], v[:, 2], self.half)
        # the outline itself inside the footprint (circular coils: the square that holds them)
        inner = _corners(v[:, :2], v[:, 2], self.half - self.spacing / 2)
        out = np.maximum(self.lo - inner.reshape(-1, 2), 0).sum() + \
            np.maximum(inner.reshape(-1, 2) - self.hi, 0).sum()
        return float(_overlap(c) + out)

    def _coil_fisher(self, i, coil) -> np.ndarray:
        """``J_i^T J_i`` ``(N, 6, 6)`` of coil ``i`` alone (cached by its placement): the
        Fisher information is a sum over the source coils, and a search step mostly moves
        one coil."""
        key = (i, float(coil.center[0]), float(coil.center[1]), float(coil.angle))
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

    def stat(self, values) -> float:
        v = np.asarray(values).ravel()
        if not np.all(np.isfinite(v)):
            return np.inf
        return float({"median": np.median, "p95": lambda a: np.percentile(a, 95),
                      "max": np.max}[self.statistic](v))

    def smooth(self, values) -> float:
        """What the search minimises: the statistic itself for the median; for the 95th
        percentile and the maximum, the mean of the values above the 90th / 98th percentile
        (an upper bound of the statistic's neighbourhood that does not jump when another
        point becomes the percentile)."""
        v = np.asarray(values).ravel()
        if not np.all(np.isfinite(v)):
            return np.inf
        if self.statistic == "median":
            return float(np.median(v))
        q = np.percentile(v, SMOOTH_PERCENTILE[self.statistic])
        return float(np.mean(v[v >= q]))

    def objective(self, x) -> float:
        """The smooth statistic, raised by the constraint penalty; the best layout that meets
        the constraints is kept as the search goes (``best``)."""
        self.evaluations += 1
        pen = self.penalty(x)
        f = self.smooth(self.position_std(x))
        if pen == 0 and f < self.best[1]:
            self.best = (np.array(x, dtype=np.float64), f)
        return f * (1.0 + 100.0 * pen / 0.01)


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
    output: str | None
    html: str | None
    bounds: object = None
    start_bounds: object = None
    board: object = None
    start_board: object = None
    _not_in_dict = ("bounds", "start_bounds", "board", "start_board")

    def lines(self) -> list:
        """The human summary (``openemt design optimize`` on stderr)."""
        a, b = self.start["position_mm"]["p95"], self.optimized["position_mm"]["p95"]
        return [f"{self.target}: p95 position bound {a:.4f} -> {b:.4f} mm "
                f"({100 * self.improvement_p95:.1f} % lower)"]


def _map_block(bm, mc, target_mm) -> dict:
    return {"position_mm": _scaled(map_summary(bm.position_std, target_mm * 1e-3), 1e3),
            "rotation_deg": _scaled(map_summary(bm.rotation_std), float(np.degrees(1.0))),
            "montecarlo": mc}


def optimize_layout(options: OptimizeOptions | None = None, **overrides) -> OptimizedLayout:
    """Optimise the coil centres and angles of a board (see the module docstring).

    Examples
    --------
    >>> from openemt.design import optimize_layout
    >>> r = optimize_layout(target="anser", grid=(3, 3, 2), orientations="down",
    ...                     max_evaluations=20, starts=1, montecarlo=0)
    >>> r.optimized["position_mm"]["p95"] <= r.start["position_mm"]["p95"]
    True
    """
    from scipy.optimize import minimize

    from ._montecarlo import montecarlo

    opts = replace(options or OptimizeOptions(), **overrides)
    if opts.statistic not in _STATISTICS:
        raise InputError(f"expected --statistic in {list(_STATISTICS)}, got {opts.statistic!r}")
    if opts.max_evaluations < 1 or opts.starts < 1:
        raise InputError(f"expected a positive --max-evaluations and --starts, got "
                         f"{opts.max_evaluations} and {opts.starts}")
    if not opts.min_spacing_mm >= 0:
        raise InputError(f"expected --min-spacing-mm >= 0, got {opts.min_spacing_mm}")
    target = resolve_target(opts.target)
    if target.board is None:
        raise InputError(f"expected a board (a built-in board, a board file or a board "
                         f"calibration) to optimise, got {target.kind} {opts.target!r}")
    start_map, volume, sigma, _ = map_of(target, opts)
    rotations = orientation_set(opts.orientations, opts.n_orientations)
    lay = _Layout(target.board, start_map.points, rotations, sigma, opts.statistic,
                  opts.min_spacing_mm * 1e-3)
    x0 = lay.vector(target.board)
    if lay.penalty(x0) > 0:
        raise InputError(f"expected a start layout within its footprint and "
                         f"{opts.min_spacing_mm:g} mm spacing, got coils closer than that")
    t0 = time.perf_counter()
    rng = np.random.default_rng(opts.seed)
    lay.objective(x0)
    per_start = max(1, (opts.max_evaluations - 1) // opts.starts)
    n_coils = len(target.board.coils)
    for k in range(opts.starts):
        xs = x0 if k == 0 else x0 + np.tile([0.01, 0.01, 0.2], len(target.board.coils)) * \
            rng.standard_normal(x0.size)
        if k and lay.penalty(xs) > 0:
            xs = x0
        # search in units of 10 mm and 0.1 rad, each centre within the footprint and each
        # angle within a quarter turn of its start (a square's angles repeat every quarter)
        scale = np.tile([0.01, 0.01, 0.1], n_coils)
        half = np.repeat([c.outer_size[0] / 2 for c in target.board.coils], 3)
        lo = np.where(np.arange(x0.size) % 3 == 2, x0 - np.pi / 4,
                      np.tile([*lay.lo, 0.0], n_coils) + half)
        hi = np.where(np.arange(x0.size) % 3 == 2, x0 + np.pi / 4,
                      np.tile([*lay.hi, 0.0], n_coils) - half)
        u0 = np.clip((xs - x0) / scale, (lo - x0) / scale, (hi - x0) / scale)
        minimize(lambda u: lay.objective(x0 + u * scale), u0, method="Powell",
                 bounds=list(zip((lo - x0) / scale, (hi - x0) / scale)),
                 options={"maxfev": per_start, "xtol": 1e-3, "ftol": 1e-4})
    best_x = lay.best[0]
    seconds = time.perf_counter() - t0
    board = lay.board_of(best_x)
    from dataclasses import replace as _r

    board = _r(board, name=f"{target.board.name}-optimized",
               description=f"{target.board.name} with coil centres and angles optimised for "
               f"the {opts.statistic} position bound (openemt design optimize)")
    opt_map = bound_map(lay.model_of(board), start_map.points, rotations, sigma)
    from ._map import montecarlo_plan

    plan = montecarlo_plan(target, opts)
    mc_start = montecarlo(target.model, start_map, sigma, n_points=opts.montecarlo,
                          trials=opts.trials, seed=opts.seed, plan=plan,
                          start=opts.montecarlo_start)
    from ..board import BoardModel

    mc_opt = montecarlo(BoardModel.from_board(board), opt_map, sigma, trials=opts.trials,
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
    if opts.output:
        from ..io import write_board

        write_board(board, opts.output)
    result = OptimizedLayout(
        target=str(opts.target), statistic=opts.statistic, volume=volume.to_dict(),
        orientations=opts.orientations, noise_sigma=sigma,
        constraints=(f"{len(board.coils)} coils of the start board (same shape, size, turns, "
                     f"drive current), planar, inside the start footprint x "
                     f"{[round(float(v) * 1e3, 2) for v in (lay.lo[0], lay.hi[0])]} mm, y "
                     f"{[round(float(v) * 1e3, 2) for v in (lay.lo[1], lay.hi[1])]} mm, "
                     f"outlines at least {opts.min_spacing_mm:g} mm apart"),
        evaluations=lay.evaluations, seconds=seconds,
        start=_map_block(start_map, mc_start, opts.target_mm),
        optimized=_map_block(opt_map, mc_opt, opts.target_mm),
        improvement_p95=float(1 - p1 / p0), improvement_statistic=float(1 - s1 / s0),
        montecarlo_improvement_p95=mc_gain, montecarlo_bound_improvement_p95=mc_bound_gain,
        coils=[{"name": c.name, "center": c.center.tolist(), "angle": float(c.angle)}
               for c in board.coils],
        output=opts.output, html=opts.html, bounds=opt_map,
        start_bounds=start_map, board=board, start_board=target.board)
    if opts.html:
        from ._html import optimize_document

        optimize_document(result).write(opts.html)
    return result
