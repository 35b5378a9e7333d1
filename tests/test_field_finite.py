"""Finite coils: physics checks of the magpylib use, far-field agreement with the dipole
model, normalisation, sensor quadrature, batch vs loop and input validation."""

import numpy as np
import pytest
from scipy.constants import mu_0

from openemt.field import (
    ANSER_COIL_CENTERS,
    Coil,
    DipoleModel,
    FiniteCoilModel,
    anser_field_generator,
    circular_coil,
    coil_fields,
    square_coil,
    square_spiral_coil,
)
from openemt.geometry import invert, pose_from_vector

DIRECTIONS = np.array([(0, 0, 1), (0, 0, -1), (1, 0, 0), (0, 1, 0), (1, 1, 1), (-1, 2, 0.5),
                       (0.3, -0.2, 1.0)], dtype=float)
DIRECTIONS /= np.linalg.norm(DIRECTIONS, axis=1, keepdims=True)


def dipole_field(moment, points):
    """B = (3 (M.u) u - M) / d^3 at points (N, 3) relative to the dipole."""
    d = np.linalg.norm(points, axis=1, keepdims=True)
    u = points / d
    return (3 * (u @ moment)[:, None] * u - moment) / d**3


def relative_deviation(coil, r_over_d, moment=None):
    """Max over DIRECTIONS of |B - B_dipole| / |B_dipole| at r = r_over_d * coil.diameter;
    the dipole moment defaults to ``gain * axis``."""
    pts = coil.center + r_over_d * coil.diameter * DIRECTIONS
    B = coil.field(pts)
    Bd = dipole_field(coil.moment if moment is None else moment, pts - coil.center)
    return np.linalg.norm(B - Bd, axis=1) / np.linalg.norm(Bd, axis=1)


def random_poses(rng, n, lo, hi):
    """Poses with translations at distance lo..hi in random directions, random rotations."""
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = u * rng.uniform(lo, hi, size=(n, 1))
    return pose_from_vector(np.column_stack([t, rng.normal(size=(n, 3))]))


# --------------------------------------------------------------------------- physics of one coil

def test_single_loop_on_axis_matches_textbook():
    R = 0.02
    loop = circular_coil((0.0, 0.0, 0.0), (0, 0, 1), radius=R)
    z = np.linspace(-0.1, 0.3, 9)
    B = loop.field(np.column_stack([np.zeros_like(z), np.zeros_like(z), z]))
    B_si = B / loop.field_scale                       # back to tesla for 1 A
    expected = mu_0 * R**2 / (2 * (R**2 + z**2) ** 1.5)
    np.testing.assert_allclose(B_si[:, 2], expected, rtol=1e-12, atol=0)
    np.testing.assert_allclose(B_si[:, :2], 0.0, atol=1e-12 * expected.max())
    # and in model units: (4 pi / mu0) * B_SI / (pi R^2) = 2 / (R^2 + z^2)^1.5
    np.testing.assert_allclose(B[:, 2], 2.0 / (R**2 + z**2) ** 1.5, rtol=1e-12)


def test_square_loop_on_axis_matches_textbook():
    a = 0.03
    loop = square_coil((0.0, 0.0, 0.0), (0, 0, 1), side=a)
    z = np.linspace(0.0, 0.2, 6)
    B_si = loop.field(np.column_stack([np.zeros_like(z), np.zeros_like(z), z])) / loop.field_scale
    expected = mu_0 * a**2 / (2 * np.pi * (z**2 + a**2 / 4) * np.sqrt(z**2 + a**2 / 2))
    np.testing.assert_allclose(B_si[:, 2], expected, rtol=1e-12)


def test_area_turns_from_geometry():
    c = circular_coil((0, 0, 0), (0, 0, 1), radius=0.02, depth=0.006, length=0.03, turns=120)
    np.testing.assert_allclose(c.area_turns, 120 * np.pi * (0.02**2 + 0.006**2 / 12), rtol=1e-13)
    s = square_coil((0, 0, 0), (1, 0, 0), side=0.04, depth=0.004, turns=50)
    np.testing.assert_allclose(s.area_turns, 50 * (0.04**2 + (2 * 0.004) ** 2 / 12), rtol=1e-13)
    sp = square_spiral_coil((0, 0, 0))
    h = (0.070 - 0.0005) / 2 - 0.00075 * np.arange(25)
    nominal = 2 * np.sum((2 * h) ** 2)          # two layers of nested squares
    np.testing.assert_allclose(sp.area_turns, nominal, rtol=2e-2)
    assert abs(sp.area_turns - nominal) > 0      # the spiral is not nested squares
    assert np.linalg.norm(sp.vector_area[:2]) < 1e-3 * sp.area_turns


@pytest.mark.parametrize("builder", [
    lambda: circular_coil((0.01, -0.02, 0.03), (1, 2, 3), radius=0.02, length=0.03, depth=0.006,
                          turns=200, gain=1.7),
    lambda: circular_coil((0, 0, 0), (0, 1, 0), radius=0.02, turns=1, gain=0.5),
    lambda: square_coil((0, 0, 0), (1, 0, 0), side=0.04, length=0.04, depth=0.002, turns=80),
    lambda: square_spiral_coil((0.05, 0.0, 0.0), 0.3, gain=2.0),
])
def test_far_field_is_the_dipole_of_moment_gain_axis(builder):
    coil = builder()
    dev50 = relative_deviation(coil, 50.0)
    assert dev50.max() < 1e-3, dev50
    # against the dipole of the coil's exact vector area (a spiral's via and feed tilt it by
    # ~2e-4 rad), the deviation falls at least as 1/r
    m = coil.gain * coil.vector_area / coil.area_turns
    exact50 = relative_deviation(coil, 50.0, m).max()
    assert relative_deviation(coil, 100.0, m).max() < 0.6 * exact50


def test_finite_size_is_measurable_at_short_range():
    loop = circular_coil((0, 0, 0), (0, 0, 1), radius=0.02)   # d = 40 mm
    for r_over_d in (4.0, 5.0, 6.0):
        dev = relative_deviation(loop, r_over_d)
        assert dev.max() > 1e-3, (r_over_d, dev)
    # thin loop, leading correction (octupole) ~ (R/r)^2: r/d 4 -> 6 shrinks it ~ (4/6)^2
    ratio = relative_deviation(loop, 6.0).max() / relative_deviation(loop, 4.0).max()
    assert 0.35 < ratio < 0.55
    spiral = square_spiral_coil((0, 0, 0))
    for r_over_d in (4.0, 5.0, 6.0):
        assert relative_deviation(spiral, r_over_d).max() > 1e-3


def test_dipole_imitating_solenoid_cancels_the_octupole():
    """A thin solenoid with length/diameter = sqrt(3)/2 ~ 0.866 has no octupole term
    (Paperno & Plotkin 2004): at r/d = 5 it is far closer to a dipole than a single loop."""
    d = 0.04
    loop = circular_coil((0, 0, 0), (0, 0, 1), radius=d / 2)
    sol = circular_coil((0, 0, 0), (0, 0, 1), radius=d / 2, length=np.sqrt(3) / 2 * d, turns=100,
                        order=(1, 6, 1))
    assert relative_deviation(sol, 5.0).max() < relative_deviation(loop, 5.0).max() / 20


def test_field_scales_as_inverse_cube_in_far_field():
    coil = square_spiral_coil((0, 0, 0), 0.2)
    r = 50 * coil.diameter
    B1 = np.linalg.norm(coil.field(r * DIRECTIONS), axis=1)
    B2 = np.linalg.norm(coil.field(2 * r * DIRECTIONS), axis=1)
    np.testing.assert_allclose(B2 / B1, 1 / 8, rtol=1e-3)


def test_gain_scales_field_and_coil_fields_stacks():
    a = circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, gain=1.0)
    b = circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, gain=-2.5)
    pts = np.random.default_rng(1).normal(size=(5, 3)) * 0.2
    F = coil_fields([a, b], pts)
    assert F.shape == (2, 5, 3)
    np.testing.assert_allclose(F[1], -2.5 * F[0], rtol=1e-13)


# --------------------------------------------------------------------------- geometry builders

def test_square_coil_frames_follow_cube_faces():
    for axis in np.eye(3):
        c = square_coil((0, 0, 0), axis, side=0.04)
        np.testing.assert_allclose(c.rotation.T @ c.rotation, np.eye(3), atol=1e-15)
        np.testing.assert_allclose(c.axis, axis)
        # sides along two other global axes
        assert np.allclose(np.sort(np.abs(c.rotation[:, 0])), [0, 0, 1])
    assert np.linalg.det(square_coil((0, 0, 0), (1, 1, 0), side=0.04).rotation) == pytest.approx(1)


def test_spiral_path_geometry():
    sp = square_spiral_coil((0, 0, 0))
    v = sp.spiral_path()
    np.testing.assert_allclose(v[0], v[-1])                                  # closed
    assert np.abs(v[:, :2]).max() == pytest.approx((0.070 - 0.0005) / 2)     # outer centreline
    assert sorted(set(np.round(v[:, 2], 12))) == pytest.approx([-0.0008, 0.0008])
    # both layers circulate counter-clockwise: z vector area of each layer is positive
    top, bottom = v[v[:, 2] > 0], v[v[:, 2] < 0]
    for layer in (top, bottom):
        assert 0.5 * np.cross(layer[:-1], layer[1:])[:, 2].sum() > 0
    one = square_spiral_coil((0, 0, 0), layers=1)
    np.testing.assert_allclose(2 * one.area_turns, sp.area_turns, rtol=1e-3)


def test_anser_field_generator_layout():
    coils = anser_field_generator(gain=1.5)
    assert len(coils) == 8
    np.testing.assert_allclose([c.center[:2] for c in coils], ANSER_COIL_CENTERS)
    np.testing.assert_allclose(ANSER_COIL_CENTERS[0], [-0.093543, 0.093543])
    for k, c in enumerate(coils):
        np.testing.assert_allclose(c.axis, [0, 0, 1], atol=1e-15)
        angle = np.arctan2(c.rotation[1, 0], c.rotation[0, 0])
        assert angle == pytest.approx(np.pi / 4 if k + 1 in (2, 4, 5, 7) else 0.0)
        assert c.gain == 1.5 and c.turns == 25 and c.layers == 2
    # footprints do not overlap: sample each coil's outline, test against the others' squares
    for a in coils:
        edge = a.spiral_path()[:, :2] @ a.rotation[:2, :2].T + a.center[:2]
        for b in coils:
            if b is a:
                continue
            local = (edge - b.center[:2]) @ b.rotation[:2, :2]
            inside = np.all(np.abs(local) < 0.035, axis=1)
            assert not inside.any()


# --------------------------------------------------------------------------- sensor quadrature

@pytest.mark.parametrize("coil", [
    circular_coil((0.01, 0.02, 0.0), (0, 1, 1), radius=0.005, length=0.01, depth=0.002, turns=30,
                  order=(2, 2, 2)),
    square_coil((0, 0, 0.01), (0, 0, 1), side=0.01, length=0.01, turns=10, order=(1, 2, 3)),
    square_spiral_coil((0, 0, 0)),
])
def test_sensor_quadrature_weights_and_moments(coil):
    pts, w = coil.sensor_quadrature()
    assert pts.shape == (len(w), 3)
    assert np.all(w > 0)
    np.testing.assert_allclose(w.sum(), 1.0, rtol=1e-14)
    np.testing.assert_allclose(w @ pts, coil.center, atol=1e-15)   # symmetric about the centre
    local = (pts - coil.center) @ coil.rotation
    if coil.kind == "circular" and coil.order[2] >= 1:
        # flux-weighted mean of x^2 over every turn's disk: r^2 / 4, r^2 averaged with area weights
        s, _, wl = coil._loops()
        mean_x2 = np.sum(wl * s**4 / 4) / np.sum(wl * s**2)
        np.testing.assert_allclose(w @ local[:, 0] ** 2, mean_x2, rtol=1e-12)


def test_point_sensor_reduces_to_moment_dot_field():
    rng = np.random.default_rng(3)
    sources = [circular_coil(0.045 * e, e, radius=0.02, length=0.0344, turns=100) for e in np.eye(3)]
    sensor = circular_coil((0.001, 0.0, 0.002), (0.2, 1, 0), radius=0.001, order=(1, 1, 0), gain=3)
    model = FiniteCoilModel(sources, [sensor], gain=0.01)
    P = random_poses(rng, 4, 0.15, 0.25)
    C = model.coupling(P)
    p = P[:, :3, :3] @ sensor.center + P[:, :3, 3]
    m = P[:, :3, :3] @ sensor.moment
    B = coil_fields(sources, p)
    np.testing.assert_allclose(C[:, :, 0], 0.01 * np.einsum("ika,ka->ki", B, m), rtol=1e-13)


def test_reciprocity_of_finite_coils():
    """Mutual inductance is symmetric: swapping source and sensor with the inverse pose gives
    the same coupling, up to the sensor area quadrature."""
    rng = np.random.default_rng(4)
    a = circular_coil((0, 0, 0.003), (0, 0, 1), radius=0.01, length=0.006, turns=40,
                      order=(1, 3, 3))
    b = square_coil((0.002, 0, 0), (1, 0, 0), side=0.012, turns=20, gain=2.0, order=(1, 1, 4))
    P = random_poses(rng, 5, 0.06, 0.1)
    C_ab = FiniteCoilModel([a], [b]).coupling(P)
    C_ba = FiniteCoilModel([b], [a]).coupling(invert(P))
    np.testing.assert_allclose(C_ab, C_ba, rtol=1e-5, atol=1e-9 * np.abs(C_ab).max())


# --------------------------------------------------------------------------- model vs dipole

def _relative(C, Cd):
    return np.abs(C - Cd).max(axis=(1, 2)) / np.abs(Cd).max(axis=(1, 2))


def test_triaxial_coupling_tends_to_dipole_equivalent():
    rng = np.random.default_rng(5)
    d = 0.04
    sources = [circular_coil(0.045 * e, e, radius=d / 2, length=0.86 * d, depth=0.004, turns=150,
                             gain=g) for e, g in zip(np.eye(3), (1.0, 0.9, 1.1))]
    sensors = [circular_coil(0.002 * e, e, radius=0.004, length=0.004, turns=60, gain=g)
               for e, g in zip(np.eye(3), (1.3, 1.2, 0.8))]
    model = FiniteCoilModel(sources, sensors)
    dip = model.dipole_equivalent()
    assert isinstance(dip, DipoleModel) and dip.gain == pytest.approx(1 / 250)
    np.testing.assert_allclose(dip.L_so, 0.045 * np.eye(3))
    np.testing.assert_allclose(dip.M_so, np.diag([1.0, 0.9, 1.1]), atol=1e-15)
    np.testing.assert_allclose(dip.M_se, np.diag([1.3, 1.2, 0.8]), atol=1e-15)
    P_far = random_poses(rng, 6, 50 * d, 60 * d)
    far = _relative(model.coupling(P_far), dip.coupling(P_far))
    assert far.max() < 1e-3, far
    P_near = random_poses(rng, 6, 4 * d, 6 * d)
    near = _relative(model.coupling(P_near), dip.coupling(P_near))
    assert near.max() > far.max()


def test_concentric_cube_source_is_concentric_dipole():
    side = 0.04
    sources = [square_coil((0, 0, 0), e, side=side + 0.002 * k, length=side, turns=100)
               for k, e in enumerate(np.eye(3))]
    sensors = [circular_coil((0, 0, 0), e, radius=0.003, length=0.003, turns=60) for e in np.eye(3)]
    model = FiniteCoilModel(sources, sensors)
    dip = model.dipole_equivalent()
    assert dip.is_concentric
    P = random_poses(np.random.default_rng(6), 4, 60 * side, 70 * side)
    assert _relative(model.coupling(P), dip.coupling(P)).max() < 1e-3


def test_anser_board_tends_to_dipole_equivalent():
    rng = np.random.default_rng(7)
    board = anser_field_generator()
    sensor = [circular_coil((0, 0, 0), (0, 0, 1), radius=0.0005, length=0.002, turns=100,
                            order=(1, 1, 0))]
    model = FiniteCoilModel(board, sensor)
    dip = model.dipole_equivalent()
    assert (dip.n_source, dip.n_sensor) == (8, 1)
    # 50 x the coil side (the board's coils are 70 mm; the board spans ~260 mm)
    P = random_poses(rng, 3, 50 * 0.070, 55 * 0.070)
    C, Cd = model.coupling(P), dip.coupling(P)
    assert C.shape == (3, 8, 1)
    rel = np.abs(C - Cd).max() / np.abs(Cd).max()
    assert rel < 1e-3, rel


# --------------------------------------------------------------------------- batch, validation

def test_batch_equals_loop(monkeypatch):
    rng = np.random.default_rng(8)
    sources = [circular_coil(0.045 * e, e, radius=0.02, length=0.03, turns=100) for e in np.eye(3)]
    sources.append(square_spiral_coil((0, 0, -0.05), 0.4, turns=5, outer_side=0.02))
    sensors = [circular_coil(0.002 * e, e, radius=0.004, length=0.004, turns=60) for e in np.eye(3)]
    model = FiniteCoilModel(sources, sensors)
    small = FiniteCoilModel(sources, sensors, chunk=500)       # many magpylib calls
    P = random_poses(rng, 7, 0.1, 0.3)
    C = model.coupling(P)
    assert C.shape == (7, 4, 3) and (model.n_source, model.n_sensor) == (4, 3)
    loop = np.concatenate([model.coupling(P[k:k + 1]) for k in range(len(P))])
    np.testing.assert_allclose(C, loop, rtol=1e-12, atol=0)
    np.testing.assert_allclose(small.coupling(P), C, rtol=1e-12, atol=0)
    import openemt.field._finite as finite
    monkeypatch.setattr(finite, "_POINTS_PER_BLOCK", 50)        # blocks of 2 poses
    np.testing.assert_allclose(model.coupling(P), C, rtol=1e-12, atol=0)
    assert model.coupling(P[:0]).shape == (0, 4, 3)


def test_pose_convention_rotation_of_sensor():
    """Rotating the sensor by 180 degrees about its own axis leaves a coaxial coupling
    unchanged; flipping it negates the coupling."""
    src = [circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, turns=10)]
    sen = [circular_coil((0, 0, 0), (0, 0, 1), radius=0.002, turns=10, order=(1, 1, 2))]
    model = FiniteCoilModel(src, sen)
    P = pose_from_vector(np.array([[0, 0, 0.1, 0, 0, 0], [0, 0, 0.1, 0, 0, np.pi],
                                   [0, 0, 0.1, np.pi, 0, 0]], dtype=float))
    C = model.coupling(P)[:, 0, 0]
    assert C[0] > 0
    np.testing.assert_allclose(C[1], C[0], rtol=1e-12)
    np.testing.assert_allclose(C[2], -C[0], rtol=1e-12)


@pytest.mark.parametrize("call, exc", [
    (lambda: circular_coil((0, 0, 0), (0, 0, 0), radius=0.01), ValueError),
    (lambda: circular_coil((0, 0), (0, 0, 1), radius=0.01), ValueError),
    (lambda: circular_coil((0, 0, np.nan), (0, 0, 1), radius=0.01), ValueError),
    (lambda: circular_coil((0, 0, 0), (0, 0, 1), radius=-0.01), ValueError),
    (lambda: circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, depth=0.03), ValueError),
    (lambda: circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, turns=0), ValueError),
    (lambda: circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, turns=2.5), TypeError),
    (lambda: circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, gain=0.0), ValueError),
    (lambda: circular_coil((0, 0, 0), (0, 0, 1), radius=0.01, order=(1, 1)), ValueError),
    (lambda: square_spiral_coil((0, 0, 0), turns=60), ValueError),
    (lambda: square_spiral_coil((0, 0, 0), layers=3), ValueError),
    (lambda: square_spiral_coil((0, 0, 0), np.diag([1.0, 1.0, -1.0])), ValueError),
    (lambda: Coil("hexagonal", (0, 0, 0), np.eye(3), 0.01), ValueError),
    (lambda: FiniteCoilModel([], [circular_coil((0, 0, 0), (0, 0, 1), radius=0.01)]), ValueError),
    (lambda: FiniteCoilModel(["coil"], [circular_coil((0, 0, 0), (0, 0, 1), radius=0.01)]),
     TypeError),
    (lambda: FiniteCoilModel([circular_coil((0, 0, 0), (0, 0, 1), radius=0.01)],
                             [circular_coil((0, 0, 0), (0, 0, 1), radius=0.01)], gain=np.inf),
     ValueError),
    (lambda: coil_fields([circular_coil((0, 0, 0), (0, 0, 1), radius=0.01)], np.zeros((4, 2))),
     ValueError),
])
def test_bad_inputs_raise_one_line_errors(call, exc):
    with pytest.raises(exc) as info:
        call()
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("expected")


@pytest.mark.parametrize("poses", [np.zeros((3, 3, 3)), np.eye(4), np.full((2, 4, 4), np.nan)])
def test_bad_poses_raise(poses):
    c = circular_coil((0, 0, 0), (0, 0, 1), radius=0.01)
    with pytest.raises(ValueError) as info:
        FiniteCoilModel([c], [c]).coupling(poses)
    assert "\n" not in str(info.value)
