"""Hemisphere specifications: which of the two mirror-image dipole solutions is meant.

A dipole coupling is unchanged when the sensor position p is replaced by -p. A hemisphere names a
direction ``n``; the solution with ``p . n >= 0`` is taken. ILEMT names hemispheres by a signed
axis (``'+x'``, ``'-z'``, docs/paper-procedure.md#iterative-solution); openemt also accepts an arbitrary 3-vector.
"""

from __future__ import annotations

import re

import numpy as np

from .._errors import InputError

__all__ = ["DEFAULT_HEMISPHERE", "hemisphere_from_positions", "hemisphere_vectors",
           "rig_hemispheres"]

#: Hemisphere every solver uses when none is given: the sensor in front of the source's x axis.
DEFAULT_HEMISPHERE = "+x"

_AXIS_RE = re.compile(r"^\s*([+-]?)\s*([xyzXYZ])\s*$")


def _one(h) -> np.ndarray:
    if isinstance(h, str):
        m = _AXIS_RE.match(h)
        if m is None:
            raise InputError(f"expected a hemisphere like '+x', '-z' or 'y', got {h!r}")
        v = np.zeros(3)
        v["xyz".index(m.group(2).lower())] = -1.0 if m.group(1) == "-" else 1.0
        return v
    v = np.asarray(h, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or not np.any(v):
        raise InputError(f"expected a hemisphere string or a finite non-zero 3-vector, got {h!r}")
    return v / np.linalg.norm(v)


def hemisphere_vectors(hemisphere, n: int, *, allow_none: bool = True) -> np.ndarray:
    """Unit hemisphere directions, shape ``(n, 3)``; rows of zeros mean "no constraint".

    Parameters
    ----------
    hemisphere : None, str, array_like (3,), sequence of str of length n, or array (n, 3)
        ``None`` (no constraint, only if ``allow_none``), one spec for all samples, or one per
        sample.
    n : int
        Number of samples.
    """
    if hemisphere is None:
        if not allow_none:
            raise InputError("expected a hemisphere such as '+x', got None")
        return np.zeros((n, 3))
    if isinstance(hemisphere, str):
        return np.tile(_one(hemisphere), (n, 1))
    arr = np.asarray(hemisphere)
    if arr.dtype.kind in "iuf":
        if arr.shape == (3,):
            return np.tile(_one(arr), (n, 1))
        if arr.shape == (n, 3):
            norms = np.linalg.norm(arr, axis=1, keepdims=True)
            if not np.all(np.isfinite(arr)) or np.any(norms == 0):
                raise InputError("expected finite non-zero hemisphere vectors, got NaN/inf/zero")
            return arr / norms
        raise InputError(f"expected hemisphere vectors of shape (3,) or ({n}, 3), got {arr.shape}")
    if arr.shape != (n,):
        raise InputError(f"expected one hemisphere per sample, shape ({n},), got {arr.shape}")
    cache: dict[str, np.ndarray] = {}
    out = np.empty((n, 3))
    for k, h in enumerate(arr.tolist()):
        if h not in cache:
            cache[h] = _one(h)
        out[k] = cache[h]
    return out


def hemisphere_from_positions(positions) -> np.ndarray:
    """ILEMT's hemisphere of known positions: the signed axis of the largest |component|.

    Returns strings like ``'+x'``, shape (N,) (docs/paper-procedure.md#iterative-solution).
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"expected positions of shape (N, 3), got {p.shape}")
    axis = np.argmax(np.abs(p), axis=1)
    sign = np.where(p[np.arange(p.shape[0]), axis] < 0, "-", "+")
    return np.char.add(sign, np.array(list("xyz"))[axis])


def rig_hemispheres(source_fixture, stage_fixture, sensor_fixture, source_codes,
                    sensor_codes) -> np.ndarray:
    """Hemisphere of the sensor on the test rig for each pair of manual fixture codes.

    The direction is the sensor's position in the source frame with the stage at its home
    (stage vector zero): ``P = F_so . so_J . F_st . F_se`` (MacLachlan et al. 2025, eq. 6).
    A rotated source fixture turns the source, so the sensor lies in a different hemisphere of
    it: ILEMT's ``YoutZup`` home puts it on +x, ``XinYup`` on +y.

    Parameters
    ----------
    source_fixture, stage_fixture, sensor_fixture : ndarray, shape (6,) or (4, 4)
        The calibration's fixture transforms F_so, F_st, F_se.
    source_codes, sensor_codes : sequence of str, length K
        Manual fixture codes of each pair.

    Returns
    -------
    ndarray, shape (K, 3)
        Home position of the sensor in the source frame (m); its direction is the hemisphere
        (pass it to the solvers as ``hemisphere``, one row per sample).

    Examples
    --------
    >>> import openemt
    >>> folder = openemt.datasets.path("cal_9_15_premo_cmu")
    >>> cal = openemt.read_ilemt_calibration(folder / "base_calibration.mat")
    >>> codes = ["YoutZup", "XinYup", "XoutZup", "ZoutYup"]
    >>> p = rig_hemispheres(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture, codes,
    ...                     ["YoutZup"] * 4)
    >>> hemisphere_from_positions(p).tolist()
    ['+x', '+y', '-y', '+z']
    """
    from ..geometry import ground_truth_poses

    so, se = list(source_codes), list(sensor_codes)
    if len(so) != len(se):
        raise InputError(f"expected as many sensor- as source-fixture codes, got {len(se)} and "
                         f"{len(so)}")
    P = ground_truth_poses(source_fixture, stage_fixture, sensor_fixture, so,
                           np.zeros((len(so), 6)), se)
    return P[:, :3, 3].copy()
