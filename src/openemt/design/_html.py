"""The self-contained HTML page of a map or an optimisation (openemt.report's document, figures
embedded as base64 PNG): slices of the bound over the volume, distributions, Monte Carlo."""

from __future__ import annotations

import numpy as np

from ..report import pyplot

__all__ = ["map_document", "optimize_document"]


def slices_figure(maps: dict, title: str):
    """Top views of the per-point RMS position bound (mm), one row per map, one panel per
    grid height (at most 5, spread over the heights)."""
    plt = pyplot()
    first = next(iter(maps.values()))
    z = np.unique(np.round(first.points[:, 2], 9))
    pick = z[np.unique(np.linspace(0, len(z) - 1, min(5, len(z))).round().astype(int))]
    vmax = max(float(np.nanmax(np.where(np.isfinite(m.point_rms()), m.point_rms(), np.nan)))
               for m in maps.values()) * 1e3
    fig, axes = plt.subplots(len(maps), len(pick), squeeze=False, layout="constrained",
                             figsize=(3.2 * len(pick) + 1.0, 3.0 * len(maps)))
    im = None
    for r, (label, m) in enumerate(maps.items()):
        v = m.point_rms() * 1e3
        for c, zz in enumerate(pick):
            ax = axes[r][c]
            sel = np.abs(m.points[:, 2] - zz) < 1e-9
            x, y = np.unique(m.points[sel, 0]), np.unique(m.points[sel, 1])
            img = v[sel].reshape(len(x), len(y)).T
            ext = [x[0] * 1e3, x[-1] * 1e3, y[0] * 1e3, y[-1] * 1e3]
            im = ax.imshow(img, origin="lower", extent=ext, vmin=0, vmax=vmax,
                           cmap="viridis", aspect="equal", interpolation="nearest")
            ax.set_title(f"{label}: z = {zz * 1e3:.0f} mm", fontsize=9)
            ax.set_xlabel("x (mm)")
            ax.set_ylabel("y (mm)")
    fig.colorbar(im, ax=axes, label="position bound, RMS over orientations (mm)")
    fig.suptitle(title)
    return fig


def distribution_figure(maps: dict):
    """Histograms of the position and rotation bounds over (point, orientation)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), layout="constrained")
    for label, m in maps.items():
        p = m.position_std.ravel() * 1e3
        r = np.degrees(m.rotation_std.ravel())
        axes[0].hist(p[np.isfinite(p)], bins=40, alpha=0.6, label=label)
        axes[1].hist(r[np.isfinite(r)], bins=40, alpha=0.6, label=label)
    axes[0].set_xlabel("position bound (mm)")
    axes[1].set_xlabel("rotation bound (deg)")
    for ax in axes:
        ax.set_ylabel("points x orientations")
        ax.legend()
    return fig


def montecarlo_figure(mc: dict):
    """Monte Carlo RMS against the bound at the sampled points."""
    plt = pyplot()
    b = np.array([p["bound_mm"] for p in mc["points"]])
    e = np.array([p["montecarlo_rms_mm"] for p in mc["points"]])
    fig, ax = plt.subplots(figsize=(4.6, 4.2), layout="constrained")
    ax.scatter(b, e, s=20)
    hi = float(np.nanmax(np.concatenate([b, e]))) * 1.1
    ax.plot([0, hi], [0, hi], "k--", lw=1, label="RMS = bound")
    ax.set_xlabel("position bound (mm)")
    ax.set_ylabel("Monte Carlo RMS error (mm)")
    ax.legend()
    return fig


def _summary_rows(d: dict) -> list:
    rows = []
    for key, label, unit in (("position_mm", "position bound", "mm"),
                             ("rotation_deg", "rotation bound", "deg")):
        s = d[key]
        rows.append({"quantity": f"{label} ({unit})", "median": s["median"], "p95": s["p95"],
                     "max": s["max"]})
    return rows


def _montecarlo_section(rep, mc: dict, what: str) -> None:
    if not mc:
        return
    rep.heading(f"Monte Carlo against the bound{what}")
    rep.paragraph(f"{mc['n_points']} sampled points, {mc['trials']} noise draws each; noise: "
                  f"{mc['noise']}; solver: {mc['solver']}. Median ratio of Monte Carlo RMS "
                  f"position error to the bound: {mc['ratio_median']:.3f} (rotation "
                  f"{mc['ratio_rotation_median']:.3f}); {mc['n_failed']} draws did not "
                  f"converge.")
    rep.figure(montecarlo_figure(mc), "Monte Carlo RMS position error against the bound")


def map_document(result):
    """The :class:`~openemt.report.Report` of a :class:`~openemt.design.DesignMap`."""
    from ..report import Report

    d = result.to_dict()
    rep = Report(f"Design map: {d['target']}")
    rep.paragraph(f"Cramer-Rao bound of the pose ({d['dof']}-DOF sensor, {d['n_source']} "
                  f"source coils, {d['n_sensor']} sensor coil(s)) over the volume "
                  f"x {d['volume']['x_mm']} mm, y {d['volume']['y_mm']} mm, z "
                  f"{d['volume']['z_mm']} mm ({d['n_points']} points x "
                  f"{d['n_orientations']} sensor orientations, '{d['orientations']}'), for "
                  f"white coupling noise of standard deviation {d['noise_sigma']:.4g} "
                  f"({d['noise']}).")
    rep.table(_summary_rows(d), caption="Bound over every point and orientation")
    rep.paragraph(f"Fraction of (point, orientation) pairs with a position bound at or below "
                  f"{d['target_mm']:g} mm: {d['position_mm']['fraction_below_target']:.3f}.")
    maps = {d["target"]: result.bounds}
    rep.figure(slices_figure(maps, "Position bound over the volume"),
               "Top views at several heights; each cell is the RMS over the orientations")
    rep.figure(distribution_figure(maps), "Distributions of the bounds")
    _montecarlo_section(rep, d["montecarlo"], "")
    return rep


def optimize_document(result):
    """The report of an :class:`~openemt.design.OptimizedLayout`: both maps side by side."""
    from ..report import Report

    d = result.to_dict()
    rep = Report(f"Layout optimisation: {d['target']}")
    rep.paragraph(f"Objective: the {d['statistic']} of the position bound over the volume "
                  f"x {d['volume']['x_mm']} mm, y {d['volume']['y_mm']} mm, z "
                  f"{d['volume']['z_mm']} mm ({d['orientations']} orientations). "
                  f"Constraints: {d['constraints']}. {d['evaluations']} evaluations in "
                  f"{d['seconds']:.1f} s. 95th-percentile improvement: "
                  f"{100 * d['improvement_p95']:.1f} %.")
    rows = []
    for label in ("start", "optimized"):
        s = d[label]["position_mm"]
        rows.append({"layout": label, "median (mm)": s["median"], "p95 (mm)": s["p95"],
                     "max (mm)": s["max"]})
    rep.table(rows, caption="Position bound over every point and orientation")
    if result.board is not None:
        rep.table([{"coil": c["name"], "x (mm)": c["center"][0] * 1e3,
                    "y (mm)": c["center"][1] * 1e3, "angle (deg)": np.degrees(c["angle"]),
                    "size (mm)": c["outer_size"] * 1e3, "turns/layer": c["turns_per_layer"]}
                   for c in d["coils"]], caption="Optimised coils")
    else:
        rep.table([{"coil": c["name"], **{f"{a} (mm)": v * 1e3 for a, v in
                                          zip("xyz", c["position"])},
                    **{f"axis {a}": v for a, v in zip("xyz", c["axis"])},
                    "|m| / start": c["moment_ratio"]} for c in d["coils"]],
                  caption="Optimised source coils (dipoles)")
    maps = {"start": result.start_bounds, "optimized": result.bounds}
    rep.figure(slices_figure(maps, "Position bound: start and optimised layouts"),
               "Top views at several heights (same colour scale)")
    if result.board is not None:
        rep.figure(layout_figure(result), "Coil outlines: start (grey) and optimised (blue)")
    rep.figure(distribution_figure(maps), "Distributions of the bounds")
    for label in ("start", "optimized"):
        _montecarlo_section(rep, d[label]["montecarlo"], f" ({label} layout)")
    return rep


def layout_figure(result):
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 5), layout="constrained")
    for board, color in ((result.start_board, "0.6"), (result.board, "tab:blue")):
        for c in board.coils:
            v = c.segments()[:, 0, :2] * 1e3
            ax.plot(v[:, 0], v[:, 1], color=color, lw=0.4)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    return fig
