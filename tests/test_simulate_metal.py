"""Metal scenes of the simulator against analytic limits (docs/simulator.md#metal-scenes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.field import DipoleModel
from openemt.simulate import (
    METAL_SCENES,
    MetalObject,
    MetalScene,
    Motion,
    metal_scene,
    sheet_reflection,
    simulate,
    skin_depth,
    sphere_polarizability,
)
from openemt.simulate._metal_physics import MU0, coaxial_mutual_inductance

GAIN = 1e-7  # mu0 / 4 pi: couplings in tesla for unit moments


def _pose(p, R=None):
    P = np.eye(4)
    P[:3, 3] = p
    if R is not None:
        P[:3, :3] = R
    return P[None]


def _axial_model():
    """One source coil at the origin along +z, one sensor coil along +z (dipoles)."""
    z = np.array([[0.0], [0.0], [1.0]])
    return DipoleModel(np.zeros((3, 1)), z, np.zeros((3, 1)), z, GAIN)


# -- sphere ---------------------------------------------------------------------------------
def test_sphere_limits():
    a, sigma = 0.02, 3.5e7
    f_low = np.array([0.001, 0.01])
    w = 2 * np.pi * f_low
    k = sphere_polarizability(a, sigma, 1.0, f_low)
    series = -1j * w * MU0 * sigma * a**2 / 30 - (w * MU0 * sigma * a**2) ** 2 / 315
    np.testing.assert_allclose(k, series, rtol=1e-5)
    # perfect conductor -2 pi a^3 H0, i.e. kappa -> -1/2; the approach scales with the skin depth
    f_high = np.array([1e7, 4e7])
    k = sphere_polarizability(a, sigma, 1.0, f_high)
    d = skin_depth(f_high, sigma)
    np.testing.assert_allclose(k, -0.5 + 0.75 * d * (1 - 1j) / a, rtol=0, atol=3 * (d / a).max()
                               ** 2)
    # permeable, non-conducting: (mu_r - 1) / (mu_r + 2)
    np.testing.assert_allclose(sphere_polarizability(a, 0.0, 1000.0, [1e3]), 999 / 1002)
    # a conducting permeable sphere starts permeable and ends a perfect conductor
    k = sphere_polarizability(a, 7e6, 100.0, [1e-3, 1e10])
    assert abs(k[0] - 99 / 102) < 1e-3 and abs(k[1] + 0.5) < 0.01


def test_sphere_scene_is_the_induced_dipole():
    model = _axial_model()
    c, a, f = np.array([0.0, 0.0, 0.3]), 0.02, 1e3
    scene = MetalScene((MetalObject("sphere", "copper", tuple(c), radius=a),))
    dC = scene.induced_couplings(model, _pose([0.0, 0.0, 0.5]), f)[0, 0, 0]
    kappa = sphere_polarizability(a, 5.96e7, 1.0, f)
    B0 = GAIN * 2 / 0.3**3                          # on-axis dipole field at the sphere
    expected = kappa * a**3 * 2 * B0 / 0.2**3        # the induced dipole's on-axis field
    np.testing.assert_allclose(dC, expected, rtol=1e-12)


# -- sheets ---------------------------------------------------------------------------------
def test_sheet_reflection_limits():
    lam = np.array([1.0, 10.0])
    np.testing.assert_allclose(sheet_reflection(lam, 1e9, 6e7, 1.0, 0.01), -1, atol=1e-3)
    np.testing.assert_allclose(sheet_reflection(lam, 1e-6, 1.0, 50.0, np.inf), 49 / 51,
                               rtol=1e-9)
    # thin sheet (d << delta): the receding-image factor -i w mu0 s / (2 lam + i w mu0 s)
    f, sigma, d = 50.0, 2.5e7, 1e-4
    g = 1j * 2 * np.pi * f * MU0 * sigma * d
    np.testing.assert_allclose(sheet_reflection(lam, f, sigma, 1.0, d), -g / (2 * lam + g),
                               rtol=1e-3)
    # a slab many skin depths thick is the half-space
    np.testing.assert_allclose(sheet_reflection(lam, 1e4, 2.5e7, 1.0, 0.05),
                               sheet_reflection(lam, 1e4, 2.5e7, 1.0, np.inf), rtol=1e-9)


def test_perfect_sheet_cancels_the_normal_field_on_its_surface():
    """On a perfect conductor B.n = 0: a coil lying on the sheet reads nothing."""
    model = DipoleModel(np.zeros((3, 1)), np.array([[0.3], [0.2], [0.9]]), np.zeros((3, 1)),
                        np.array([[0.0], [0.0], [1.0]]), GAIN)
    scene = MetalScene((MetalObject("sheet", {"conductivity": 1e16}, (0, 0, -0.1),
                                    thickness=0.01),))
    for x in (0.0, 0.07, 0.2):
        P = _pose([x, 0.05, -0.1 + 1e-9])
        C0 = model.coupling(P)[0, 0, 0]
        dC = scene.induced_couplings(model, P, 1e6)[0, 0, 0]
        assert abs(C0 + dC) < 1e-6 * abs(C0)
    # and the tangential field doubles (a coil along x just above the sheet)
    tang = dataclasses.replace(model, M_se=np.array([[1.0], [0.0], [0.0]]))
    P = _pose([0.1, 0.05, -0.1 + 1e-6])
    np.testing.assert_allclose(scene.induced_couplings(tang, P, 1e6)[0, 0, 0],
                               tang.coupling(P)[0, 0, 0], rtol=1e-4)


def test_sheet_needs_the_tracker_on_its_front():
    scene = MetalScene((MetalObject("sheet", "aluminium", (0, 0, 0.1), thickness=0.002),))
    with pytest.raises(InputError, match="tracker's side"):
        scene.induced_couplings(_axial_model(), _pose([0, 0, 0.2]), 1e3)


# -- loop networks --------------------------------------------------------------------------
def _ring_response(f, sigma=5.96e7, R=0.05, a=1e-4, z_src=0.4, z_sen=0.3):
    model = _axial_model()
    scene = MetalScene((MetalObject("ring", {"conductivity": sigma}, (0, 0, z_src),
                                    radius=R, wire_radius=a),))
    return scene.induced_couplings(model, _pose([0, 0, z_src + z_sen]), f)[0, 0, 0]


def test_ring_is_the_r_l_circuit():
    """A thin ring: I = -i w Phi / (R + i w L) with Phi the source flux through it
    (on-axis dipole flux 2 pi gain m R^2 / (R^2 + z^2)^1.5), its field on the axis
    mu0 I R^2 / (2 (R^2 + z^2)^1.5) and the classic low-frequency inductance of a round wire
    ring mu0 R (ln(8 R / a) - 7/4) (external plus the internal mu0 / 8 pi per metre)."""
    sigma, R, a, zs, zr = 5.96e7, 0.05, 1e-4, 0.4, 0.3
    res = 2 * np.pi * R / (sigma * np.pi * a**2)
    L = MU0 * R * (np.log(8 * R / a) - 1.75)
    phi = 2 * np.pi * GAIN * R**2 / (R**2 + zs**2) ** 1.5
    for f in (10.0, 300.0, 1e4):
        w = 2 * np.pi * f
        current = -1j * w * phi / (res + 1j * w * L)
        expected = MU0 * current * R**2 / (2 * (R**2 + zr**2) ** 1.5)
        # 64-gon filament and the wire's own skin effect (a << delta here): within 0.5 %
        np.testing.assert_allclose(_ring_response(f, sigma, R, a, zs, zr), expected, rtol=5e-3)


def test_coaxial_mutual_inductance_far_limit():
    """Two far coaxial loops: M = mu0 pi r1^2 r2^2 / (2 z^3)."""
    r1, r2, z = 0.01, 0.02, 1.0
    np.testing.assert_allclose(coaxial_mutual_inductance(r1, r2, z),
                               MU0 * np.pi * r1**2 * r2**2 / (2 * z**3), rtol=1e-3)


def _disk_moment(f, sigma=2.5e7, a=0.05, d=1e-4, K=16):
    """The physical moment (A m^2) of a disk in a (nearly) uniform axial field B0 = 1 T."""
    model = _axial_model()
    zs, zr = 5.0, 2.0           # source far away: uniform field at the disk
    scene = MetalScene((MetalObject("disk", {"conductivity": sigma}, (0, 0, zs), radius=a,
                                    thickness=d, filaments=K),))
    dC = scene.induced_couplings(model, _pose([0, 0, zs + zr]), f)[0, 0, 0]
    B0 = GAIN * 2 / zs**3
    return dC / (1e-7 * 2 / zr**3) / B0           # the on-axis field of the moment


def test_thin_disk_low_frequency_moment():
    """A thin disk at low frequency: J = -i w sigma B0 r / 2, m = -i w sigma d pi a^4 / 8."""
    f, sigma, a, d = 1.0, 2.5e7, 0.05, 1e-4
    m = _disk_moment(f, sigma, a, d)
    expected = -1j * 2 * np.pi * f * sigma * d * np.pi * a**4 / 8
    assert abs(m.imag / expected.imag - 1) < 0.01
    assert abs(m.real) < 0.05 * abs(m.imag)


def test_thin_disk_perfect_conductor_limit():
    """A perfectly conducting thin disk in an axial field: m = -(8/3) a^3 H0 (Landau &
    Lifshitz, Electrodynamics of Continuous Media, §3 problem)."""
    a = 0.05
    m = _disk_moment(1e6, 6e7, a, 1e-3, K=16)
    expected = -8 / 3 * a**3 / MU0
    assert abs(m / expected - 1) < 0.03, m / expected


def test_square_plate_low_frequency_moment():
    """A thin square plate (side s) at low frequency: the stream function of its eddy currents
    solves the torsion problem, so m = -i w sigma d B0 J / 4 with Saint-Venant's torsion
    constant J = 0.1406 s^4 (Timoshenko & Goodier, Theory of Elasticity, §109). The
    concentric-rectangle network gives s^4 / 32 = 0.0313 s^4 instead of 0.0352 s^4: 11 % low
    (its currents turn square corners); this test holds it to that documented figure."""
    f, sigma, d, side = 1.0, 2.5e7, 1e-4, 0.1
    model = _axial_model()
    zs, zr = 5.0, 2.0
    scene = MetalScene((MetalObject("plate", {"conductivity": sigma}, (0, 0, zs),
                                    size=(side, side), thickness=d, filaments=16),))
    dC = scene.induced_couplings(model, _pose([0, 0, zs + zr]), f)[0, 0, 0]
    m = dC / (1e-7 * 2 / zr**3) / (GAIN * 2 / zs**3)
    exact = -1j * 2 * np.pi * f * sigma * d * 0.1406 * side**4 / 4
    ratio = m.imag / exact.imag
    assert 0.86 < ratio < 0.91, ratio


# -- scenes ---------------------------------------------------------------------------------
def test_scene_toml_round_trip(tmp_path):
    text = """
sample_period_s = 0.05
[[object]]
kind = "ring"
material = "stainless steel"
position = [0.2, 0.0, 0.1]
rotation = [0.0, 1.5707963, 0.0]
radius = 0.2
wire_radius = 0.01
[object.motion]
kind = "waypoints"
times = [0.0, 10.0]
positions = [[0.0, 0.0, 0.0], [0.0, 0.3, 0.0]]
[[object]]
kind = "sphere"
material = {conductivity = 3e7, mu_r = 1.0}
position = [0.0, 0.1, 0.0]
radius = 0.01
"""
    path = tmp_path / "scene.toml"
    path.write_text(text)
    scene = MetalScene.from_toml(path)
    assert len(scene.objects) == 2 and scene.sample_period_s == 0.05 and scene.moving
    again = MetalScene.from_dict(scene.to_dict())
    assert again.to_dict() == scene.to_dict()
    off = scene.objects[0].motion.offset([0.0, 5.0, 20.0])
    np.testing.assert_allclose(off[:, 1], [0.0, 0.15, 0.3])
    with pytest.raises(InputError, match="material"):
        MetalScene.from_dict({"object": [{"kind": "sphere", "material": "gold",
                                          "radius": 0.01}]})
    with pytest.raises(InputError, match="radius"):
        MetalScene.from_dict({"object": [{"kind": "disk", "material": "copper",
                                          "thickness": 0.01}]})
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match="binary data"):
        MetalScene.from_toml(tmp_path / "bin.toml")
    (tmp_path / "bad.toml").write_text('[[object]]\nkind = "sheet"\nmaterial = "copper"\n'
                                       'thickness = -1\n')
    with pytest.raises(InputError, match=r"bad\.toml: .*thickness"):
        MetalScene.from_toml(tmp_path / "bad.toml")


@pytest.mark.parametrize("name", METAL_SCENES)
def test_named_scenes_on_the_rig(name):
    clean = simulate("dipole-approx", "md", source_fixtures="YoutZup",
                     sensor_fixtures="YoutZup", stage_sigma=0)
    data = simulate("dipole-approx", "md", source_fixtures="YoutZup", sensor_fixtures="YoutZup",
                    stage_sigma=0, metal=name)
    assert np.iscomplexobj(data.couplings)
    rel = np.linalg.norm(data.couplings - clean.couplings, axis=(1, 2)) / \
        np.linalg.norm(clean.couplings, axis=(1, 2))
    if name == "clean":
        assert rel.max() == 0
    else:
        assert 1e-3 < np.median(rel) < 0.5
    assert data.meta["errors"]["metal"]["name"] == name


def test_moving_object_changes_with_time():
    scene = MetalScene((MetalObject("sphere", "aluminium", (0.1, 0.0, 0.0), radius=0.02,
                                    motion=Motion("linear", velocity=(0.0, 0.01, 0.0))),))
    model = DipoleModel.concentric(gain=GAIN)
    P = np.repeat(_pose([0.0, 0.0, 0.15]), 3, axis=0)
    dC = scene.induced_couplings(model, P, [1e3, 2e3, 3e3], t=[0.0, 0.0, 5.0])
    np.testing.assert_array_equal(dC[0], dC[1])
    assert np.abs(dC[2] - dC[0]).max() > 0.1 * np.abs(dC[0]).max()


@pytest.mark.parametrize("kind", ["single", "dual", "triad"])
def test_board_models_see_the_scene(kind):
    """A board (finite coil traces) with 1-, 2- and 3-coil sensors: the sheet's image of the
    traces agrees with the image of their dipole equivalents far from the board."""
    from openemt.board import BoardModel, builtin_board

    b = builtin_board("anser")
    b = dataclasses.replace(b, sensor=dataclasses.replace(b.sensor, kind=kind))
    model = BoardModel.from_board(b)
    scene = MetalScene((MetalObject("sheet", "copper", (0, 0, -0.5), thickness=0.01),))
    P = _pose([0.01, 0.02, 0.6])
    dC = scene.induced_couplings(model, P, np.full(8, 1e4))
    assert dC.shape == (1, 8, model.n_sensor) and np.all(np.isfinite(dC))
    # far from the board: its coils are dipoles of moment mu0/4pi * area-turns * normal
    moments = np.stack([c.area_turns * np.asarray(c.normal) / np.linalg.norm(c.normal)
                        for c in b.coils])
    sensor = b.sensor
    dip = DipoleModel(np.stack([c.center for c in b.coils], 1), moments.T,
                      sensor.coil_positions()[:1].T, sensor.coil_axes()[:1].T, GAIN)
    one = scene.induced_couplings(dip, P, np.full(8, 1e4))[0, :, 0]
    np.testing.assert_allclose(dC[0, :, 0] / model.sensor_gains[0], one, rtol=0,
                               atol=0.02 * np.abs(one).max())


def test_named_scenes_follow_the_volume():
    lo, hi = np.array([-0.1, -0.1, 0.05]), np.array([0.1, 0.1, 0.25])
    sheet = metal_scene("aluminium_sheet", volume=(lo, hi)).objects[0]
    assert sheet.kind == "sheet" and sheet.position[2] == pytest.approx(0.05 - 0.1)
    assert sheet.thickness == 0.002 and sheet.material.name == "aluminium"
    plate = metal_scene("steel_plate", volume=(lo, hi)).objects[0]
    assert plate.position[0] == pytest.approx(0.2) and plate.material.mu_r > 1
    ring = metal_scene("moving_ring", volume=(lo, hi)).objects[0]
    assert ring.motion.moving
    with pytest.raises(InputError, match="scene name"):
        metal_scene("brass_tray")


def test_simulate_command_metal_and_bands(tmp_path, capsys):
    import json

    from openemt.cli import main
    from openemt.io import read_dataset

    scene = tmp_path / "scene.toml"
    scene.write_text('[[object]]\nkind = "disk"\nmaterial = "titanium"\n'
                     'position = [0.0, 0.244, -0.134]\nradius = 0.1\nthickness = 0.002\n')
    out = tmp_path / "sim.h5"
    code = main(["simulate", "--preset", "dipole-approx", "--pattern", "md",
                 "--source-fixtures", "YoutZup", "--sensor-fixtures", "YoutZup",
                 "--metal", str(scene), "--bands", "274,334,370;7500,10500,13500",
                 "-o", str(out), "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["complex"] and summary["errors"]["metal"]["object"][0]["kind"] == "disk"
    data = read_dataset(out)
    assert data.band_couplings.shape == (142, 2, 3, 3)
    np.testing.assert_array_equal(data.band_frequencies,
                                  [[274, 334, 370], [7500, 10500, 13500]])
    bad = tmp_path / "bad.h5"
    code = main(["simulate", "--preset", "dipole-approx", "--metal", str(tmp_path / "no.toml"),
                 "-o", str(bad)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: expected an existing metal scene file")
    assert not bad.exists()
