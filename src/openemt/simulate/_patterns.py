"""Commanded stage motion patterns of the ILEMT calibration apparatus (docs/ilemt-data.md#patterns).

Every pattern is an ``(N, 6)`` array of SI stage vectors ``[x, y, z, a, b, c]`` (m, rad) in the
order the stage visits them, exactly as the ILEMT logger writes them (columns 1-6 of a ``.dat``
file, converted from mm/degrees). The stage has only X, Y, Z and Rz axes, so ``a = b = 0``.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError

__all__ = ["GRID_PITCH", "PATTERNS", "STAGE_Z_LIMIT", "stage_pattern"]

#: Lowest Z the stage reaches (m). A commanded Z below it is logged as this value (docs/ilemt-data.md#z-clipping).
STAGE_Z_LIMIT = -0.0462
#: Pitch of the Anser-style 7 x 7 test grid (m).
GRID_PITCH = 0.04286

_RZ5 = (-90.0, -45.0, 0.0, 45.0, 90.0)


def _grid_mesh(values_mm, key_mm, rz_deg) -> np.ndarray:
    """ILEMT mesh: per Rz (outer loop), the first grid point, the key point, then the rest.

    Grid points are ordered x fastest, then y, then z; a null row starts and ends the pattern.
    Returns mm/deg rows.
    """
    v = np.asarray(values_mm, dtype=np.float64)
    z, y, x = np.meshgrid(v, v, v, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    block = np.vstack([pts[:1], np.asarray(key_mm, dtype=np.float64)[None], pts[1:]])
    rows = [np.zeros((1, 6))]
    for rz in rz_deg:
        b = np.zeros((block.shape[0], 6))
        b[:, :3] = block
        b[:, 5] = rz
        rows.append(b)
    rows.append(np.zeros((1, 6)))
    return np.vstack(rows)


def _source_mesh() -> np.ndarray:
    """The older ``source`` pattern: z fastest, then y, then x; key z = -37.5 second; Rz = 0."""
    xs = (-70.0, -35.0, 0.0, 35.0, 70.0)
    ys = (-70.0, 0.0, 70.0)
    zs = (-50.0, -25.0, 0.0, 25.0, 50.0)
    x, y, z = np.meshgrid(xs, ys, zs, indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    pts = np.vstack([pts[:1], [[-70.0, -70.0, -37.5]], pts[1:]])
    rows = np.zeros((pts.shape[0] + 2, 6))
    rows[1:-1, :3] = pts
    return rows


def _sweep() -> np.ndarray:
    """``axis_sweep_05_05``: single-axis sweeps at 0.5 mm / 0.5 deg with null rows between.

    null; X -50..50 (201); null; Y (201); null; Z (201); null; one Rx row (stage has no Rx: 0);
    null; one Ry row (0); null; Rz -90..90 (361); null -> 973 rows.
    """
    lin = np.linspace(-50.0, 50.0, 201)
    rz = np.linspace(-90.0, 90.0, 361)
    null = np.zeros((1, 6))
    parts = [null]
    for axis in range(3):
        b = np.zeros((lin.size, 6))
        b[:, axis] = lin
        parts += [b, null]
    parts += [np.zeros((1, 6)), null, np.zeros((1, 6)), null]  # Rx and Ry "sweeps": one row each
    b = np.zeros((rz.size, 6))
    b[:, 5] = rz
    parts += [b, null]
    return np.vstack(parts)


def _grid() -> np.ndarray:
    """Anser-style 7 x 7 grid in the stage XY plane (x fastest, then y), no rotation, no nulls."""
    v = (np.arange(7) - 3) * GRID_PITCH * 1e3
    y, x = np.meshgrid(v, v, indexing="ij")
    rows = np.zeros((49, 6))
    rows[:, 0] = x.ravel()
    rows[:, 1] = y.ravel()
    return rows


def _trans_only(rows: np.ndarray) -> np.ndarray:
    """``trans_only_subset``: the rows whose rotation columns are all exactly zero."""
    return rows[np.all(rows[:, 3:] == 0.0, axis=1)]


def _md():
    return _grid_mesh((-50.0, 0.0, 50.0), (-25.0, -50.0, -50.0), _RZ5)


def _ld():
    return _grid_mesh((-50.0, -25.0, 0.0, 25.0, 50.0), (-37.5, -50.0, -50.0), _RZ5)


_BUILDERS = {
    "sd": lambda: _grid_mesh((-50.0, 0.0, 50.0), (-25.0, -50.0, -50.0), (-45.0, 0.0, 45.0)),
    "md": _md,
    "ld": _ld,
    "mdtrans": lambda: _trans_only(_md()),
    "ldtrans": lambda: _trans_only(_ld()),
    "sweep": _sweep,
    "source": _source_mesh,
    "grid": _grid,
}

#: Names accepted by :func:`stage_pattern`, with their row counts.
PATTERNS = {"sd": 86, "md": 142, "ld": 632, "mdtrans": 30, "ldtrans": 128, "sweep": 973,
            "source": 78, "grid": 49}


def stage_pattern(name: str, *, clip_z: bool = True) -> np.ndarray:
    """Commanded stage vectors of a named ILEMT motion pattern.

    Parameters
    ----------
    name : str
        ``md`` (3x3x3 grid {-50, 0, 50} mm + key point, Rz in {-90, -45, 0, 45, 90} deg, 142
        rows), ``ld`` (5x5x5 + key, 632), ``sweep`` (single-axis sweeps, 973), ``mdtrans`` /
        ``ldtrans`` (the rows of md / ld with zero rotation, 30 / 128), ``sd`` (86),
        ``source`` (78) or ``grid`` (Anser-style 7 x 7 grid at 42.86 mm pitch, 49 rows).
    clip_z : bool, default True
        Replace commanded Z values below the stage travel limit ``STAGE_Z_LIMIT`` (-46.2 mm)
        by the limit, as the real stage logs them. ``False`` gives the nominal grid (-50 mm).

    Returns
    -------
    stage : ndarray, shape (N, 6)
        ``[x, y, z, a, b, c]`` in m and rad, in visiting order (null rows included).

    References
    ----------
    docs/ilemt-data.md#patterns; MacLachlan et al. 2025, §VIII-D.
    """
    if not isinstance(name, str) or name not in _BUILDERS:
        raise InputError(f"expected a stage pattern name in {sorted(_BUILDERS)}, got {name!r}")
    rows = _BUILDERS[name]()
    out = np.empty_like(rows)
    out[:, :3] = rows[:, :3] * 1e-3
    out[:, 3:] = np.deg2rad(rows[:, 3:])
    if clip_z:
        out[:, 2] = np.maximum(out[:, 2], STAGE_Z_LIMIT)
    return out
