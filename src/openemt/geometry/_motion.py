"""Rotation diversity of a set of poses: does the motion determine a rotation it is used for?

Fits that recover a constant rotation from rigid motions (the ``A X = Y B`` hand-eye problem, a
reference calibration's hand-eye start, pivot calibration) need rotations about at least two
non-parallel axes: rotations about one axis leave the rotation about that axis undetermined,
whatever the solver. This is a property of the motion, known before any fit, so it is tested
first and its error names the cause, instead of surfacing later as a failed fit whose message
depends on rounding.

The measure is scale-free (translations play no part) and frame-free: the rotations ``R_i`` are
taken relative to their chordal mean ``M`` (``R_i M^T``); the covariance of the rotation vectors
of those relative rotations has eigenvalues ``l1 >= l2 >= l3``. ``sqrt(l2)`` is the RMS rotation
about the best second axis; ``atan(sqrt(l2 / l1))`` is how close to one axis the rotations stay.
Rotations ``R_i = G Rz(t_i)`` or ``Rz(t_i) G`` (a turntable, a robot's last joint alone) give
``l2 = 0`` exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .._errors import InputError

__all__ = ["MIN_SECOND_AXIS_DEG", "RotationDiversity", "require_rotation_diversity",
           "rotation_diversity"]

#: RMS rotation (deg) about a second, non-parallel axis below which a set of rotations counts as
#: rotations about one axis (docs/alignment.md#how-many-pairs).
MIN_SECOND_AXIS_DEG = 2.0


@dataclass(frozen=True)
class RotationDiversity:
    """Spread of a set of rotations about their mean (see the module docstring).

    Attributes
    ----------
    n : int
        Number of rotations.
    axis : ndarray, shape (3,)
        Dominant rotation axis (unit vector, in the frame the rotations map into).
    primary_deg : float
        RMS rotation about the dominant axis (deg).
    second_deg : float
        RMS rotation about the best second axis (deg).
    within_deg : float
        The rotations lie within this angle of one axis: ``atan(second / primary)`` (deg).
    """

    n: int
    axis: np.ndarray
    primary_deg: float
    second_deg: float
    within_deg: float

    @property
    def ok(self) -> bool:
        """True when the rotations turn about at least two non-parallel axes."""
        return self.second_deg >= MIN_SECOND_AXIS_DEG

    def reason(self) -> str:
        """Why the rotations do not determine a rotation ('' when they do)."""
        if self.ok:
            return ""
        if self.primary_deg < MIN_SECOND_AXIS_DEG:
            return (f"got no rotation (RMS {self.primary_deg:.2f} deg about the mean "
                    f"orientation, {MIN_SECOND_AXIS_DEG:g} deg about each of two axes needed)")
        return (f"got rotations within {self.within_deg:.2f} deg of one axis (RMS "
                f"{self.second_deg:.2f} deg about any second axis, {MIN_SECOND_AXIS_DEG:g} deg "
                "needed)")


def rotation_diversity(poses_or_rotations) -> RotationDiversity:
    """Measure how many independent axes a set of rotations turns about.

    Parameters
    ----------
    poses_or_rotations : array_like, shape (N, 4, 4) or (N, 3, 3)
        Poses or rotation matrices; only the rotations are used.

    Returns
    -------
    RotationDiversity

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.spatial.transform import Rotation
    >>> R = Rotation.from_rotvec(np.outer(np.linspace(0, 1, 5), [0, 0, 1])).as_matrix()
    >>> d = rotation_diversity(R)
    >>> d.ok, round(d.second_deg, 6)
    (False, 0.0)
    >>> rotation_diversity(Rotation.random(20, random_state=0).as_matrix()).ok
    True
    """
    M = np.asarray(poses_or_rotations, dtype=np.float64)
    if M.ndim != 3 or M.shape[1:] not in ((4, 4), (3, 3)) or len(M) == 0:
        raise InputError(f"expected poses (N, 4, 4) or rotations (N, 3, 3), got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise InputError("expected finite poses, got non-finite values")
    rot = Rotation.from_matrix(M[:, :3, :3])
    w = (rot * rot.mean().inv()).as_rotvec()
    lam, vec = np.linalg.eigh(w.T @ w / len(w))
    lam = np.clip(lam[::-1], 0.0, None)
    primary, second = np.rad2deg(np.sqrt(lam[:2]))
    within = float(np.rad2deg(np.arctan2(np.sqrt(lam[1]), np.sqrt(lam[0]))))
    return RotationDiversity(n=len(w), axis=vec[:, -1].copy(), primary_deg=float(primary),
                             second_deg=float(second), within_deg=within)


def require_rotation_diversity(poses_or_rotations, what: str) -> RotationDiversity:
    """:func:`rotation_diversity`, raising ``InputError`` when the rotations turn about one axis.

    ``what`` names the unknown the rotations must determine (e.g. ``"X and Y of A X = Y B"``).
    """
    d = rotation_diversity(poses_or_rotations)
    if not d.ok:
        raise InputError(f"expected rotations about at least two non-parallel axes to determine "
                         f"{what}, {d.reason()}: add poses turned about another axis")
    return d
