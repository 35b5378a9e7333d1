"""Simulated reference-pose collections: a robot arm or an optical tracker carries the sensor.

The sensor is rigidly fixed to the robot flange or the optical marker by an unknown transform X,
and the reference's base (robot base, camera) sits near the field generator at an unknown
transform Y. With the hand-eye convention of :func:`openemt.align.fit_axyb`
(``A_i X = Y B_i``, docs/alignment.md#the-model), the sensor pose in the source frame is

    P_i = Y B_i X^-1,

so the reference reports ``B_i = Y^-1 P_i X`` (plus its own noise) while the tracker measures
the couplings of ``P_i``. Poses are drawn in the tracker's volume: positions uniform in the box
spanned by the preset's ``md`` calibration pattern, orientations uniform in a ball of rotation
vectors around the preset's home orientation (docs/reference-calibration.md#simulation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import __version__
from .._errors import InputError, check_nonnegative
from ..calibrate._reference import reference_block
from ..field import DipoleModel
from ..geometry import ground_truth_poses, invert, pose_from_rt, pose_from_vector, vector_from_pose
from ..io import Calibration, Dataset
from ._apparatus import truth_calibration
from ._errors import add_noise, noise_sigma
from ._patterns import stage_pattern
from ._presets import get_preset

__all__ = [
    "REFERENCE_KINDS",
    "ReferenceKind",
    "nominal_calibration",
    "reference_truth_calibration",
    "simulate_reference",
    "working_volume",
]


@dataclass(frozen=True)
class ReferenceKind:
    """A kind of reference device and its default set-up.

    Attributes
    ----------
    name : str
    noise_trans : float
        Stated translation noise of one reference pose, 3-D RMS (m).
    noise_rot : float
        Stated rotation noise, RMS rotation angle (rad).
    rotation_range : float
        Largest rotation (rad) of a drawn orientation away from the home orientation.
    X, Y : ndarray, shape (6,)
        Default true X (reference tool -> sensor) and Y (reference frame -> source frame) as
        pose vectors (m, rad).
    """

    name: str
    noise_trans: float
    noise_rot: float
    rotation_range: float
    X: tuple
    Y: tuple


#: Reference devices: a robot arm (flange pose, ~0.05 mm / 0.02 deg) and an optical tracker
#: (marker pose, ~0.25 mm / 0.1 deg); X and Y are plausible mounting transforms.
REFERENCE_KINDS = {
    "robot": ReferenceKind("robot", 0.05e-3, np.deg2rad(0.02), np.deg2rad(45.0),
                           X=(0.0031, -0.0017, -0.1184, 0.31, -0.22, 1.05),
                           Y=(0.52, 0.06, -0.34, 0.12, -0.07, 2.61)),
    "optical": ReferenceKind("optical", 0.25e-3, np.deg2rad(0.1), np.deg2rad(35.0),
                             X=(0.0124, 0.0452, -0.0368, -0.42, 0.18, -2.2),
                             Y=(1.18, 0.43, 0.61, 1.1, -0.9, 0.35)),
}


def _kind(reference) -> ReferenceKind:
    if isinstance(reference, ReferenceKind):
        return reference
    if reference not in REFERENCE_KINDS:
        raise InputError(f"expected a reference kind in {sorted(REFERENCE_KINDS)}, got "
                         f"{reference!r}")
    return REFERENCE_KINDS[reference]



def _pose(v, name) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape == (6,):
        a = pose_from_vector(a)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise InputError(f"expected `{name}` as a pose vector (6,) or a pose (4, 4), got "
                         f"shape {a.shape}")
    return a


def working_volume(preset):
    """The working volume of a preset (a name or a :class:`Preset`): the corners ``lo, hi``
    (m, source frame) of the box of its ``md`` pattern's sensor positions, and the sensor's
    home orientation ``R0`` (3, 3), both with the home fixtures."""
    p = get_preset(preset)
    stage = stage_pattern("md")
    home = (p.source_fixtures[0], p.sensor_fixtures[0])
    P = ground_truth_poses(p.source_fixture, p.stage_fixture, p.sensor_fixture, home[0], stage,
                           home[1])
    t = P[:, :3, 3]
    R0 = ground_truth_poses(p.source_fixture, p.stage_fixture, p.sensor_fixture, home[0],
                            np.zeros((1, 6)), home[1])[0, :3, :3]
    return t.min(axis=0), t.max(axis=0), R0


def _ball(rng, n, radius) -> np.ndarray:
    """``n`` rotation vectors uniform in the ball of ``radius`` (rad)."""
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * radius * np.cbrt(rng.random(n))[:, None]


def _perturbations(rng, n, sigma_t, sigma_r) -> np.ndarray:
    """Random poses with isotropic translation (3-D RMS ``sigma_t``) and rotation (RMS angle
    ``sigma_r``): each axis gets sigma / sqrt(3)."""
    v = np.empty((n, 6))
    v[:, :3] = sigma_t / np.sqrt(3.0) * rng.standard_normal((n, 3))
    v[:, 3:] = sigma_r / np.sqrt(3.0) * rng.standard_normal((n, 3))
    return pose_from_vector(v)


def reference_truth_calibration(preset, X, Y) -> Calibration:
    """The preset's dipole-equivalent model with the true X and Y as a calibration.

    The fixtures follow docs/reference-calibration.md#calibration-file: ``source_fixture`` zero,
    ``stage_fixture`` = Y, ``sensor_fixture`` = X^-1; ``extra['reference']`` holds X and Y.
    """
    X, Y = _pose(X, "X"), _pose(Y, "Y")
    cal = truth_calibration(preset)
    return cal.replace(source_fixture=np.zeros(6), stage_fixture=vector_from_pose(Y),
                       sensor_fixture=vector_from_pose(invert(X)),
                       extra={**cal.extra, "reference": reference_block(X, Y)})


def nominal_calibration(preset) -> Calibration:
    """A data-sheet start for a preset: concentric coils along the axes, each moment the length
    of the true one (no offsets, no cross terms), unknown fixtures zero. Mode ``nominal``.

    It satisfies the gauge of docs/paper-procedure.md#gauge, so it can start a reference
    calibration of simulated data without knowing the truth. A board preset's nominal model is
    its board file with the nominal gain of every coil, no offsets and equal sensor gains.
    """
    from ..field import CouplingModel

    p = get_preset(preset)
    if isinstance(p.model, CouplingModel):       # a board: its file's nominal geometry and gain
        from ..board import BoardModel
        from ._presets import board_gain_scale

        board = p.model.board
        return Calibration(model=BoardModel.from_board(board, gains=board_gain_scale(board)),
                           mode="nominal",
                           provenance={"openemt_version": __version__, "preset": p.name,
                                       "generator": "openemt.simulate.nominal_calibration"},
                           extra={"preset": p.name})
    d = p.dipole

    def axes(M):
        n = M.shape[1]
        out = np.zeros((3, n))
        norms = np.linalg.norm(M, axis=0)
        for j in range(n):
            out[min(j, 2) if n == 3 else 2, j] = norms[j]
        return out

    model = DipoleModel(np.zeros_like(d.L_so), axes(d.M_so), np.zeros_like(d.L_se),
                        axes(d.M_se), d.gain)
    return Calibration(model=model, mode="nominal",
                       provenance={"openemt_version": __version__, "preset": p.name,
                                   "generator": "openemt.simulate.nominal_calibration"},
                       extra={"preset": p.name})


def simulate_reference(preset="concentric", reference="robot", n_poses: int = 300, *,
                       X=None, Y=None, noise_trans=None, noise_rot=None, rotation_range=None,
                       snr_db=None, noise_abs=None, seed=0) -> Dataset:
    """Simulate couplings measured at poses given by a robot arm or an optical tracker.

    Parameters
    ----------
    preset : str or Preset
        Simulated tracker with a 6-DOF sensor (``concentric``, ``dipole-approx``,
        ``anser-6dof``); its coupling model (finite coils) generates the couplings.
    reference : {'robot', 'optical'} or ReferenceKind
        Reference device: default noise, rotation range, X and Y (:data:`REFERENCE_KINDS`).
    n_poses : int
        Number of poses (>= 3).
    X, Y : pose vector (6,) or pose (4, 4), optional
        True reference tool -> sensor and reference frame -> source frame transforms.
    noise_trans, noise_rot : float, optional
        Reference pose noise: 3-D RMS translation (m) and RMS rotation angle (rad); each axis
        gets sigma / sqrt(3).
    rotation_range : float, optional
        Largest rotation (rad) of the drawn orientations away from the home orientation.
    snr_db, noise_abs : float, optional
        Coupling noise as in :func:`openemt.simulate.simulate` (at most one).
    seed : int

    Returns
    -------
    Dataset
        ``couplings`` (N, n_so, n_se); ``poses`` = true sensor poses in the source frame;
        ``extra['reference_poses']`` = the reference's poses B_i as reported (noisy),
        ``extra['reference_poses_true']`` without noise, ``extra['noise_sigma']``; ``stage``
        zero, pattern = the reference kind; ``meta['reference']`` = kind, stated noise and the
        hemisphere of the volume; ``meta['truth']`` = X and Y.
    """
    p = get_preset(preset)
    if p.n_sensor == 1:
        raise InputError(f"expected a preset with a 6-DOF sensor (two or more coils) for a "
                         f"reference collection, got {p.name!r} with {p.n_sensor} sensor coil")
    k = _kind(reference)
    n = int(n_poses)
    if n < 3:
        raise InputError(f"expected n_poses >= 3, got {n_poses!r}")
    X = _pose(k.X if X is None else X, "X")
    Y = _pose(k.Y if Y is None else Y, "Y")
    st = check_nonnegative(k.noise_trans if noise_trans is None else noise_trans, "noise_trans")
    sr = check_nonnegative(k.noise_rot if noise_rot is None else noise_rot, "noise_rot")
    rr = check_nonnegative(k.rotation_range if rotation_range is None else rotation_range,
                 "rotation_range")
    if snr_db is not None and noise_abs is not None:
        raise InputError(f"expected at most one of snr_db and noise_abs, got snr_db={snr_db!r} "
                         f"and noise_abs={noise_abs!r}")

    pose_rng, ref_rng, noise_rng = np.random.default_rng(seed).spawn(3)
    lo, hi, R0 = working_volume(p)
    t = lo + (hi - lo) * pose_rng.random((n, 3))
    R = pose_from_vector(np.column_stack([np.zeros((n, 3)), _ball(pose_rng, n, rr)]))[:, :3, :3]
    P = pose_from_rt(R @ R0, t)
    B_true = invert(Y) @ P @ X
    B = B_true @ _perturbations(ref_rng, n, st, sr)

    C = p.model.coupling(P)
    if snr_db is not None or noise_abs is not None:
        sigma = noise_sigma(C, snr_db=snr_db, noise_abs=noise_abs)
        C = add_noise(C, sigma, noise_rng)
    else:
        sigma = np.zeros(n)
    centre = 0.5 * (lo + hi)
    meta = {
        "generator": "openemt.simulate.simulate_reference",
        "kind": "reference",
        "preset": p.name,
        "description": p.description,
        "source": p.source,
        "sensor": p.sensor,
        "seed": seed if seed is None else int(seed),
        "reference": {
            "kind": k.name,
            "noise_trans_m": st,
            "noise_rot_rad": sr,
            "noise_definition": "translation: 3-D RMS; rotation: RMS angle (each axis "
                                "sigma / sqrt(3)), applied in the reference tool's frame",
            "hemisphere": (centre / np.linalg.norm(centre)).tolist(),
            "rotation_range_rad": rr,
        },
        "errors": {
            "snr_db": None if snr_db is None else float(snr_db),
            "noise_abs": None if noise_abs is None else float(noise_abs),
            "reference_noise_trans_m": st,
            "reference_noise_rot_rad": sr,
        },
        "truth": {"finite_coils": bool(p.finite), "X": X.tolist(), "Y": Y.tolist()},
        "units": {"reference_poses": "m", "couplings": "dimensionless (gain 1/250 convention)"},
        "provenance": {"openemt_version": __version__, "simulated": True},
    }
    return Dataset(couplings=C, stage=np.zeros((n, 6)), source_fixture="", sensor_fixture="",
                   pattern=k.name, file_index=np.zeros(n, dtype=np.int64), files=(k.name,),
                   poses=P, extra={"reference_poses": B, "reference_poses_true": B_true,
                                   "noise_sigma": sigma}, meta=meta)
