"""Simulated trackers: finite-coil source and sensor models with true fixture transforms.

A preset is the ground truth of a simulated apparatus: the coil geometry that generates the
couplings (finite coils, so the dipole model used by calibration and solving is only an
approximation of it, as for real hardware), the dipole-equivalent model, and the true fixture
transforms F_so, F_st, F_se of the calibration rig (MacLachlan et al. 2025, eq. 6).

The dipole-equivalent parameters of the ILEMT-style presets follow the gauge of MacLachlan et al. 2025, eq. 7
(Z coils at their frame origins along +z, source Z gain 1, no Y component in the X-coil
moments), so a calibration of simulated data can be compared with the truth entry by entry.
Their values are chosen near the ILEMT calibrations quoted in docs/ilemt-data.md#calibration-mat.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import field as _field
from .._errors import InputError
from ..field import ILEMT_GAIN, DipoleModel
from ..geometry import SENSOR_FIXTURES, SOURCE_FIXTURES
from ..signal import ILEMT_FREQUENCIES  # ILEMT high-rate carriers (MacLachlan et al. 2025, §VIII-E)

__all__ = ["PRESETS", "Preset", "anser_preset", "get_preset"]


@dataclass(frozen=True, eq=False)
class Preset:
    """Ground truth of a simulated tracker and calibration rig.

    Attributes
    ----------
    name : str
        Preset name (``concentric``, ``dipole-approx``, ``anser``).
    description : str
        One line for reports.
    model : object
        Coupling model that generates the simulated couplings; has ``.coupling(poses (N, 4, 4))
        -> (N, n_source, n_sensor)``, ``.n_source`` and ``.n_sensor`` (a finite-coil model).
    dipole : DipoleModel
        The dipole-equivalent model of ``model`` (its far-field limit).
    source_fixture, stage_fixture, sensor_fixture : ndarray, shape (6,)
        True F_so, F_st, F_se as pose vectors ``[x, y, z, rx, ry, rz]`` (m, rad).
    source_fixtures, sensor_fixtures : tuple of str
        Manual fixture codes the rig supports, home first.
    default_pattern : str
        Stage pattern used when none is given.
    frequencies : ndarray, shape (n_source,)
        Drive frequency of each source coil (Hz); sets the response of conductive objects.
    source, sensor : dict
        JSON-serialisable descriptions of the coils (geometry, gains).
    metal_model : object, optional
        The coupling model whose coil geometry metal scenes see (a board model with the
        traces of the source coils, equal to ``model``'s couplings); None: ``model`` when it
        is a board model, else ``dipole`` (:func:`openemt.simulate.scene_model`).
    """

    name: str
    description: str
    model: Any
    dipole: DipoleModel
    source_fixture: np.ndarray
    stage_fixture: np.ndarray
    sensor_fixture: np.ndarray
    source_fixtures: tuple[str, ...]
    sensor_fixtures: tuple[str, ...]
    default_pattern: str
    frequencies: np.ndarray
    source: dict = field(default_factory=dict)
    sensor: dict = field(default_factory=dict)
    metal_model: Any = None

    def __post_init__(self):
        # presets are cached and shared: callers must not modify these arrays in place (they
        # are not flagged read-only because scipy's Rotation.from_rotvec rejects such input)
        for name in ("source_fixture", "stage_fixture", "sensor_fixture", "frequencies"):
            object.__setattr__(self, name, np.array(getattr(self, name), dtype=np.float64))

    @property
    def n_source(self) -> int:
        return self.dipole.n_source

    @property
    def n_sensor(self) -> int:
        return self.dipole.n_sensor

    @property
    def finite(self) -> bool:
        """True when ``model`` is a finite-coil model (not the dipole model itself)."""
        return self.model is not self.dipole




# Finite coils use the field module's default quadrature (converged to a few 1e-6 at
# r/d = 3.75, docs/field-models.md), so the simulated truth is the physical coil.


def _windings(L, M, size, length, *, square: bool):
    """Finite windings at columns of L with dipole moments = columns of M.

    ``square``: square windings of mean side ``size`` (around a cube core); else circular
    windings of mean radius ``size``.
    """
    coils = []
    for j in range(L.shape[1]):
        g = float(np.linalg.norm(M[:, j]))
        kw = {"length": float(length[j]), "gain": g}
        if square:
            coils.append(_field.square_coil(L[:, j], M[:, j] / g, side=float(size[j]), **kw))
        else:
            coils.append(_field.circular_coil(L[:, j], M[:, j] / g, radius=float(size[j]), **kw))
    return tuple(coils)


def _coil_desc(kind, L, M, size, length, square):
    return {"kind": kind, "winding": "square" if square else "circular",
            "positions_m": np.round(L, 9).tolist(), "moments": np.round(M, 9).tolist(),
            ("side_m" if square else "radius_m"): list(map(float, size)),
            "length_m": list(map(float, length))}


def _finite_model(sources, sensors) -> tuple[Any, DipoleModel]:
    model = _field.FiniteCoilModel(sources, sensors, gain=ILEMT_GAIN)
    return model, model.dipole_equivalent()


def _tri_axial_preset(name, description, L_so, M_so, s_so, l_so, L_se, M_se, F_so, F_st, F_se,
                      source_kind, square_source: bool) -> Preset:
    L_so, M_so, L_se, M_se = (np.asarray(a, dtype=np.float64) for a in (L_so, M_so, L_se, M_se))
    model, dipole = _finite_model(
        _windings(L_so, M_so, s_so, l_so, square=square_source),
        _windings(L_se, M_se, _SENSOR_R, _SENSOR_LEN, square=False))
    return Preset(
        name=name, description=description, model=model, dipole=dipole,
        source_fixture=np.asarray(F_so, dtype=np.float64),
        stage_fixture=np.asarray(F_st, dtype=np.float64),
        sensor_fixture=np.asarray(F_se, dtype=np.float64),
        source_fixtures=SOURCE_FIXTURES, sensor_fixtures=SENSOR_FIXTURES,
        default_pattern="md", frequencies=np.array(ILEMT_FREQUENCIES),
        source=_coil_desc(source_kind, L_so, M_so, s_so, l_so, square_source),
        sensor=_coil_desc("tri-axial (Premo-like)", L_se, M_se, _SENSOR_R, _SENSOR_LEN, False))


# A Premo-like 3-axis sensor: three concentric ~10 mm windings, nearly orthogonal, with
# sub-millimetre offsets. Columns are coils X, Y, Z.
_SENSOR_L = [[0.00008, -0.00002, 0.0], [0.00016, 0.00013, 0.0], [-0.00011, -0.00009, 0.0]]
_SENSOR_R = (0.0050, 0.0048, 0.0046)
_SENSOR_LEN = (0.0100, 0.0100, 0.0100)
# 180 deg about (-1, -1, 0)/sqrt2 (sensor mounted upside down, X <-> Y) with a small tilt
_F_SE = [-0.00034, 0.00026, -0.00030, -2.2078, -2.2263, -0.0032]


def _concentric() -> Preset:
    k = 0.40  # sensor gain near the cal_9_15 Premo fit
    return _tri_axial_preset(
        "concentric",
        "ferrite-cube style concentric tri-axial source (~40 mm) with a Premo-like sensor",
        L_so=[[-0.0024, 0.0002, 0.0], [0.0013, -0.0003, 0.0], [0.0011, 0.0010, 0.0]],
        M_so=[[0.82, -0.0155, 0.0], [0.0, 0.898, 0.0], [0.0016, 0.0015, 1.0]],
        # three nested square windings around a 40 mm cube, 36 mm long (air-core field; the
        # core only raises the moment, which the gains stand for). A winding as long as its
        # side would be nearly a dipole; the shorter, nested windings deviate by ~0.3 % at
        # 200 mm, which costs ~0.7 mm RMS with the exact dipole-equivalent model
        s_so=(0.040, 0.042, 0.044), l_so=(0.036, 0.036, 0.036),
        L_se=_SENSOR_L,
        M_se=[[0.993 * k, 0.0022 * k, 0.0], [0.0, 0.988 * k, 0.0], [0.0155 * k, 0.0115 * k, k]],
        F_so=[0.0012, -0.0004, -0.0088, 0.035, 0.041, -1.5701],       # ~ Rz(-90 deg)
        F_st=[0.0126, 0.2424, 0.0086, -0.0150, 0.0011, 0.0128],       # ~ 242 mm along +Y
        F_se=_F_SE,
        source_kind="concentric tri-axial (ferrite cube style)", square_source=True)


def _dipole_approx() -> Preset:
    k = 0.16  # sensor gain near the cal_9_24 Premo fit
    r = 0.020
    return _tri_axial_preset(
        "dipole-approx",
        "three separate dipole-approximating air coils (45 mm offsets) with a Premo-like sensor",
        # MacLachlan et al. 2025, Table I / cal_9_24: X and Y coils ~45 mm from the Z coil
        L_so=[[0.0453, -0.0008, 0.0], [0.0014, 0.0454, 0.0], [-0.0437, -0.0430, 0.0]],
        M_so=[[0.951, -0.0007, 0.0], [0.0, 0.949, 0.0], [-0.0259, 0.0005, 1.0]],
        # each coil 40 mm across with length/diameter = sqrt(3)/2, the solenoid shape whose
        # leading (octupole) deviation from a dipole field vanishes
        s_so=(r, r, r), l_so=(np.sqrt(3.0) * r,) * 3,
        L_se=[[0.00014, 0.00006, 0.0], [0.00012, 0.00012, 0.0], [-0.00022, -0.00019, 0.0]],
        M_se=[[0.984 * k, 0.0024 * k, 0.0], [0.0, 0.979 * k, 0.0], [0.0152 * k, 0.0120 * k, k]],
        # deliberately rotated source (63 deg) so the sensor is in the +X+Y+Z octant (cal_9_24)
        F_so=[-0.0117, -0.0094, -0.0643, 0.7571, -0.3127, -0.7452],
        F_st=[-0.0002, 0.2436, 0.0128, 0.0017, 0.0032, 0.0093],
        F_se=[-0.00033, 0.00020, -0.00037, -2.2079, -2.2263, -0.0043],
        source_kind="three separate air coils (dipole approximating)", square_source=False)


# Anser-style board: the sensor is carried over the board on the 7 x 7 test grid about 72 mm
# up, its coil axis along the board's -z. Drive frequencies are assumed (evenly spaced).
_ANSER_HEIGHT = 0.072
_ANSER_FREQUENCIES = tuple(np.linspace(2500.0, 20000.0, 8))


def anser_preset(board=None) -> Preset:
    """The ``anser`` preset with the source coils of ``board`` (a board file or built-in name,
    default the built-in ``anser``; docs/planar.md#board-file)."""
    from ..board import BoardModel, board_coils
    from ..io import load_board

    b = load_board(board)
    sources = board_coils(b)
    if len(sources) != 8:
        raise InputError(f"expected a board of 8 source coils for the anser preset, got "
                         f"{len(sources)}")
    gain_se = 0.01  # couplings of order 0.1 at the test height
    # 0.5 mm x 8 mm 5-DOF sensor coil; at this size the cross-section shape is irrelevant, and a
    # square winding samples the field on the coil axis (2 points along the length), which is
    # 4x cheaper than the circular winding's ring of points
    side, length = 0.0005, 0.008
    sensor = _field.square_coil(np.zeros(3), np.array([0.0, 0.0, 1.0]), side=side,
                                length=length, gain=gain_se)
    model, dipole = _finite_model(tuple(sources), (sensor,))
    return Preset(
        name="anser",
        description="Anser-style planar 8-coil field generator with a single-coil 5-DOF sensor",
        model=model, dipole=dipole, **_anser_rig(),
        source={"kind": "Anser-style planar board, 8 square spiral coils (board file anser)",
                "positions_m": np.round(dipole.L_so, 9).tolist(),
                "moments": np.round(dipole.M_so, 9).tolist()},
        sensor={"kind": "single coil (5-DOF)", "side_m": side, "length_m": length,
                "gain": gain_se},
        # the same couplings from the board's traces (tests/test_simulate_metal.py)
        metal_model=BoardModel.from_board(b, gains=board_gain_scale(b)))


def _anser_rig() -> dict:
    return dict(
        source_fixture=np.array([0.0004, -0.0003, 0.0, 0.0, 0.0, 0.0021]),
        stage_fixture=np.array([0.0007, -0.0005, _ANSER_HEIGHT, 0.0015, -0.0012, 0.0]),
        sensor_fixture=np.array([0.0, 0.0, 0.0, np.pi, 0.0, 0.0]),  # coil axis along -z
        # the board can only be turned in its own plane; ZoutYup/XinYup would put the sensor
        # path through the board
        source_fixtures=("YoutZup", "XoutZup"), sensor_fixtures=SENSOR_FIXTURES,
        default_pattern="grid", frequencies=np.array(_ANSER_FREQUENCIES))


#: Manufacturing tolerances of the ``anser-6dof`` preset's board and sensor (seeded, so the
#: truth is fixed): coil gains 2 % RMS, coil offsets 0.3 mm RMS per axis, the second sensor
#: coil's gain 3 % above the first's.
_BOARD_TOLERANCES = {"seed": 6, "gain_rms": 0.02, "offset_rms_m": 0.0003,
                     "sensor_gain_2": 1.03}


def _anser_6dof() -> Preset:
    """The Anser board read by the two-coil 6-DOF sensor of ``anser-6dof.toml``; its truth is
    the board model with manufacturing tolerances (:data:`_BOARD_TOLERANCES`), so a
    calibration from the board file's nominal values has something to find."""
    from ..board import BoardModel, board_coils, builtin_board

    board = builtin_board("anser-6dof")
    scale = board_gain_scale(board)
    t = _BOARD_TOLERANCES
    rng = np.random.default_rng(t["seed"])
    truth = BoardModel.from_board(
        board, gains=scale * (1 + t["gain_rms"] * rng.standard_normal(8)),
        offsets=t["offset_rms_m"] * rng.standard_normal((8, 3)),
        sensor_gains=[1.0, t["sensor_gain_2"]])
    sensor = board.sensor
    # the dipole equivalent (coil positions and moments) only sizes the live simulator
    coils = tuple(_field.square_coil(pos, ax, side=0.0005, length=sensor.length, gain=0.01)
                  for pos, ax in zip(sensor.coil_positions(), sensor.coil_axes()))
    _, dipole = _finite_model(tuple(board_coils(board)), coils)
    return Preset(
        name="anser-6dof",
        description="Anser-style planar 8-coil field generator with a two-coil 6-DOF sensor "
                    "(coils 60 degrees apart)",
        model=truth, dipole=dipole, **_anser_rig(),
        source={"kind": "Anser-style planar board, 8 square spiral coils (board file "
                        "anser-6dof), gains and offsets with manufacturing tolerances",
                "tolerances": dict(t)},
        sensor={"kind": "two coils (6-DOF)", **sensor.to_dict()})


def board_gain_scale(board) -> float:
    """The coupling of the simulated sensor coil (0.5 mm x 8 mm, gain 0.01, as the ``anser``
    preset's) per unit board-model gain: the nominal gain of a board model of these presets."""
    from dataclasses import replace

    from ..board import BoardModel, board_coils
    from ..geometry import pose_from_vector

    b = board
    coil = _field.square_coil(np.zeros(3), np.array([0.0, 0.0, 1.0]), side=0.0005,
                              length=b.sensor.length, gain=0.01)
    fin = _field.FiniteCoilModel(tuple(board_coils(b))[:1], (coil,), gain=ILEMT_GAIN)
    one = replace(b, sensor=replace(b.sensor, kind="single", angle=0.0, separation=0.0),
                  coils=b.coils[:1])
    P = pose_from_vector(np.array([[0.01, 0.02, 0.1, 0.2, 0.1, 0.0]]))
    return float(fin.coupling(P)[0, 0, 0] / BoardModel.from_board(one).coupling(P)[0, 0, 0])


_BUILDERS = {"concentric": _concentric, "dipole-approx": _dipole_approx, "anser": anser_preset,
             "anser-6dof": _anser_6dof}
#: Names accepted by :func:`get_preset`.
PRESETS = tuple(_BUILDERS)


@functools.cache
def _cached(name: str) -> Preset:
    return _BUILDERS[name]()


def get_preset(name) -> Preset:
    """The simulated tracker named ``name`` (``concentric``, ``dipole-approx``, ``anser`` or
    ``anser-6dof``).

    A :class:`Preset` passed in is returned unchanged.

    Examples
    --------
    >>> from openemt.simulate import get_preset
    >>> p = get_preset("dipole-approx")
    >>> p.n_source, p.n_sensor, p.finite, p.source_fixtures[0]
    (3, 3, True, 'YoutZup')
    """
    if isinstance(name, Preset):
        return name
    if not isinstance(name, str) or name not in _BUILDERS:
        raise InputError(f"expected a preset name in {list(PRESETS)}, got {name!r}")
    return _cached(name)
