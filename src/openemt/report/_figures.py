"""matplotlib figures of tracker errors (MacLachlan et al. 2025, Figs. 8 and 10 style) and error histograms.

Every function takes plain arrays in SI units, returns a ``matplotlib.figure.Figure`` and never
shows it; mm and degrees appear only on the axes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["error_histogram_figure", "error_map_figure", "error_vector_figure", "pyplot",
           "sweep_figure"]


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend (unless one is chosen)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def error_vector_figure(positions, errors, *, exaggeration: float | None = None,
                        title: str = "Translation error across the workspace"):
    """3-D error vectors at the reference positions (MacLachlan et al. 2025, Fig. 8 style),
    coloured by their magnitude, with the colour bar of that scale.

    Parameters
    ----------
    positions : ndarray, shape (N, 3)
        Reference positions (m).
    errors : ndarray, shape (N, 3)
        Measured minus reference position (m).
    exaggeration : float, optional
        Scale applied to the error vectors; by default chosen so the largest vector is a quarter
        of the workspace extent.
    """
    plt = pyplot()
    p = np.asarray(positions, dtype=float) * 1e3
    e = np.asarray(errors, dtype=float) * 1e3
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(e), axis=1)
    p, e = p[ok], e[ok]
    emax = np.linalg.norm(e, axis=1).max() if len(e) else 0.0
    if exaggeration is None:
        extent = np.ptp(p, axis=0).max() if len(p) else 1.0
        exaggeration = 0.25 * extent / emax if emax > 0 else 1.0
    fig = plt.figure(figsize=(7.5, 6.5))
    ax = fig.add_subplot(projection="3d")
    mag = np.linalg.norm(e, axis=1)
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=4, c="k")
    norm = plt.Normalize(0.0, emax or 1.0)
    cmap = plt.get_cmap("viridis")
    if len(p):
        ax.quiver(p[:, 0], p[:, 1], p[:, 2], e[:, 0] * exaggeration, e[:, 1] * exaggeration,
                  e[:, 2] * exaggeration, colors=cmap(norm(mag)), linewidth=0.8,
                  arrow_length_ratio=0.15)
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6, pad=0.1,
                 label="error magnitude (mm)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.set_title(f"{title}\n(vectors exaggerated {exaggeration:.0f}x; max {emax:.3f} mm)")
    return fig


def error_histogram_figure(trans_err, rot_err, *, title: str = "Error distribution"):
    """Histograms of translation (mm) and rotation (deg) error magnitudes (inputs m and rad)."""
    plt = pyplot()
    t = np.asarray(trans_err, dtype=float) * 1e3
    r = np.rad2deg(np.asarray(rot_err, dtype=float))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for ax, x, label in ((axes[0], t, "translation error (mm)"),
                         (axes[1], r, "rotation error (deg)")):
        x = x[np.isfinite(x)]
        ax.hist(x, bins=40, color="#4878a8")
        if x.size:
            rms = np.sqrt(np.mean(x ** 2))
            ax.axvline(rms, color="k", ls="--", label=f"RMS {rms:.3f}")
            ax.legend()
        ax.set_xlabel(label)
        ax.set_ylabel("count")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def sweep_figure(curves, *, title: str = "Axis sweeps: absolute error and nonlinearity"):
    """MacLachlan et al. 2025, Fig. 10 style: one panel per quantity, one line per swept axis.

    Parameters
    ----------
    curves : dict
        ``{axis_name: {"position": (n,), "position_unit": "mm"|"deg", "panels": {panel_title:
        (n,) values}}}``; panels with the same title across axes share a subplot.
    """
    plt = pyplot()
    titles: list[str] = []
    for c in curves.values():
        for k in c["panels"]:
            if k not in titles:
                titles.append(k)
    n = max(len(titles), 1)
    cols = 2
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(10, 3.2 * rows), squeeze=False)
    for idx, ttl in enumerate(titles):
        ax = axes[idx // cols][idx % cols]
        for axis_name, c in curves.items():
            if ttl in c["panels"]:
                ax.plot(c["position"], c["panels"][ttl], label=axis_name, lw=1)
        ax.set_title(ttl, fontsize=10)
        ax.set_xlabel("swept axis position (mm or deg)")
        ax.legend(fontsize=8)
    for idx in range(len(titles), rows * cols):
        axes[idx // cols][idx % cols].axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def error_map_figure(points, errors, *, failed=None, tolerance: float = 1e-3,
                     title: str = "Position error per grid point"):
    """Top view of grid points coloured by position-error magnitude, with the in-plane error
    vectors; one panel per grid height (heights within ``tolerance`` m share a panel, at most
    six panels, the rest joined to the last).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Known positions (m).
    errors : ndarray, shape (N, 3)
        Solved minus known position (m); NaN rows are points without a solution.
    failed : ndarray of bool, shape (N,), optional
        Points drawn as crosses (no converged solution); default: the NaN rows of ``errors``.
    """
    plt = pyplot()
    p = np.asarray(points, dtype=float)
    e = np.asarray(errors, dtype=float)
    bad = ~np.all(np.isfinite(e), axis=1) if failed is None else np.asarray(failed, bool)
    mag = np.where(bad, np.nan, np.linalg.norm(np.where(np.isfinite(e), e, 0.0), axis=1)) * 1e3
    z = p[:, 2]
    order = np.argsort(z, kind="stable")
    layer = np.zeros(len(p), dtype=int)
    layer[order] = np.concatenate([[0], np.cumsum(np.diff(z[order]) > tolerance)]) if len(p) \
        else np.zeros(0, int)
    layer = np.minimum(layer, 5)
    n = int(layer.max()) + 1 if len(p) else 1
    cols = min(n, 3)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols + 1.0, 4.2 * rows), squeeze=False,
                             layout="constrained")
    vmax = np.nanmax(mag) if np.any(np.isfinite(mag)) else 1.0
    sc = None
    for k in range(n):
        ax = axes[k // cols][k % cols]
        m = layer == k
        good = m & ~bad
        px, py = p[:, 0] * 1e3, p[:, 1] * 1e3
        sc = ax.scatter(px[good], py[good], c=mag[good], cmap="viridis", vmin=0,
                        vmax=vmax or 1.0, s=60)
        if np.any(good):
            # the longest in-plane arrow is 0.8 of the median grid pitch of the panel
            ux = np.unique(np.round(np.concatenate([px[m], py[m]]), 3))
            pitch = float(np.median(np.diff(ux))) if len(ux) > 1 else 1.0
            inplane = np.hypot(e[good, 0], e[good, 1]).max() * 1e3
            scale = inplane / (0.8 * pitch) if inplane > 0 else 1.0
            ax.quiver(px[good], py[good], e[good, 0] * 1e3, e[good, 1] * 1e3, angles="xy",
                      scale_units="xy", scale=scale, color="k", width=0.004)
        if np.any(m & bad):
            ax.scatter(px[m & bad], py[m & bad], marker="x", c="r", s=50, label="no solution")
            ax.legend(fontsize=8)
        zs = z[m] * 1e3
        ax.set_title(f"z = {zs.min():.1f} mm" if np.ptp(zs) < 1 else
                     f"z = {zs.min():.1f} to {zs.max():.1f} mm", fontsize=10)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_aspect("equal", adjustable="datalim")
    for k in range(n, rows * cols):
        axes[k // cols][k % cols].axis("off")
    if sc is not None:
        fig.colorbar(sc, ax=axes.ravel().tolist(), label="position error (mm)", shrink=0.85)
    fig.suptitle(f"{title} (arrows: in-plane error, scaled to the grid pitch; max "
                 f"{vmax:.3f} mm)")
    return fig
