"""NDI Toolbox TSV and generic pose CSV importers; static averaging with jitter."""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from openemt.geometry import pose_from_rt, rotation_z
from openemt.io import average_static, read_ndi_tsv, read_poses_csv, write_poses_csv

HEADER = ("Tools\tPort\tFrame\tFace\tState\tQ0\tQx\tQy\tQz\tTx\tTy\tTz\tError\tMarkers"
          "\tPort\tFrame\tFace\tState\tQ0\tQx\tQy\tQz\tTx\tTy\tTz\tError\tMarkers")


def _tool_fields(port, frame, state, q=None, t=None, err=0.12):
    if q is None:
        return [port, str(frame), "1", state] + [""] * 9
    return [port, str(frame), "1", state] + [f"{v:.8f}" for v in q] + \
        [f"{v:.4f}" for v in t] + [f"{err:.4f}", "0"]


def _write_fixture(path, rng, n=40):
    """Two tools; tool 10A static near a 90 deg z rotation, tool 10B moving; some bad rows."""
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    q_a = np.array([c, 0.0, 0.0, s])  # scalar-first: +90 deg about z
    t_a = np.array([10.0, -20.0, -250.0])  # mm
    truth_b = []
    lines = [HEADER]
    for k in range(n):
        qa = Rotation.from_rotvec(np.deg2rad(0.02) * rng.standard_normal(3)) * \
            Rotation.from_quat(q_a, scalar_first=True)
        ta = t_a + 0.05 * rng.standard_normal(3)
        fa = _tool_fields("10A", 1000 + k, "OK", qa.as_quat(scalar_first=True), ta)
        if k == 3:
            fa = _tool_fields("10A", 1000 + k, "Missing")
        if k == 7:
            fa = _tool_fields("10A", 1000 + k, "Partially Out of Volume",
                              qa.as_quat(scalar_first=True), ta)
        rb = Rotation.from_rotvec([0.1 * k, -0.05, 0.2])
        tb = np.array([k * 1.0, 5.0, -200.0 - k])
        truth_b.append(pose_from_rt(rb.as_matrix(), tb * 1e-3))
        fb = _tool_fields("10B", 1000 + k, "OK", rb.as_quat(scalar_first=True), tb, err=0.3)
        if k in (11, 12):
            fb = _tool_fields("10B", 1000 + k, "Out of Volume")
        lines.append("\t".join(["2"] + fa + fb))
    path.write_text("\n".join(lines) + "\n")
    return np.array(truth_b)


def test_ndi_tsv_parsed_from_fixture(tmp_path):
    rng = np.random.default_rng(20)
    f = tmp_path / "aurora_export.tsv"
    truth_b = _write_fixture(f, rng)
    rec = read_ndi_tsv(f)
    assert [t.port for t in rec.tools] == ["10A", "10B"]
    a, b = rec.tool("10A"), rec.tool("10B")
    assert a.n_rows == 40 and b.n_rows == 40
    assert a.skipped == {"Missing": 1, "Partially Out of Volume": 1}
    assert b.skipped == {"Out of Volume": 2}
    assert len(a.poses) == 38 and len(b.poses) == 38
    assert 1003 not in a.frame and 1007 not in a.frame and a.frame[0] == 1000
    # units: mm -> m; quaternion is scalar-first (a 90 deg z rotation, not a 180 deg one)
    np.testing.assert_allclose(a.poses[:, :3, 3].mean(axis=0), [0.010, -0.020, -0.250],
                               atol=5e-5)
    np.testing.assert_allclose(a.poses[0, :3, :3], rotation_z(np.pi / 2), atol=2e-3)
    np.testing.assert_allclose(a.error, 0.12e-3)
    keep = np.setdiff1d(np.arange(40), [11, 12])
    np.testing.assert_allclose(b.poses, truth_b[keep], atol=1e-7)
    np.testing.assert_array_equal(b.line, keep + 2)
    # the static tool: averaged, with jitter close to the simulated 0.05 mm per axis
    avg = a.average()
    assert avg.counts.tolist() == [38]
    assert 0.05e-3 < avg.jitter_trans_rms[0] < 0.12e-3
    assert np.deg2rad(0.015) < avg.jitter_rot_rms[0] < np.deg2rad(0.05)
    assert avg.jitter_trans_max[0] >= avg.jitter_trans_rms[0]
    s = rec.summary()
    assert s["tools"][1]["n_skipped"] == 2
    with pytest.raises(KeyError):
        rec.tool("99")


def test_ndi_comma_separated_and_bad_header(tmp_path):
    f = tmp_path / "x.csv"
    f.write_text("Port,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers\n"
                 "1,5,1,OK,1,0,0,0,1,2,3,0.1,0\n"
                 "1,6,1,Disabled,,,,,,,,,\n")
    rec = read_ndi_tsv(f)
    t = rec.tools[0]
    assert t.port == "1" and len(t.poses) == 1 and t.skipped == {"Disabled": 1}
    np.testing.assert_allclose(t.poses[0], pose_from_rt(np.eye(3), [1e-3, 2e-3, 3e-3]))
    g = tmp_path / "bad.tsv"
    g.write_text("Frame\tQ0\n1\t1\n")
    with pytest.raises(ValueError, match="Port"):
        read_ndi_tsv(g)
    h = tmp_path / "bad2.tsv"
    h.write_text("Port\tFrame\tState\tQ0\tQx\tQy\tQz\tTx\tTy\tTz\n1\t1\tOK\t0\t0\t0\t0\t1\t1\t1\n")
    with pytest.raises(ValueError, match="quaternion"):
        read_ndi_tsv(h)
    # a frame number that is no integer (a fraction, or beyond int64) is refused by line,
    # not cast to garbage
    for frame, shown in (("5.5", "5.5"), ("1e30", "1e+30")):
        k = tmp_path / "frame.csv"
        k.write_text("Port,Frame,Face,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,Markers\n"
                     f"1,{frame},1,OK,1,0,0,0,1,2,3,0.1,0\n")
        with pytest.raises(ValueError,
                           match=rf"expected an integer frame on line 2 .* got {re.escape(shown)}$"):
            read_ndi_tsv(k)


def test_average_static_groups_and_jitter():
    rng = np.random.default_rng(21)
    base = pose_from_rt(Rotation.random(3, random_state=5).as_matrix(),
                        rng.uniform(-0.2, 0.2, (3, 3)))
    P, g = [], []
    for i in range(3):
        for _ in range(200):
            dR = Rotation.from_rotvec(np.deg2rad(0.1) * rng.standard_normal(3)).as_matrix()
            P.append(pose_from_rt(base[i, :3, :3] @ dR, base[i, :3, 3] + 1e-4 * rng.standard_normal(3)))
            g.append(f"p{i}")
    avg = average_static(np.array(P), np.array(g))
    assert avg.labels.tolist() == ["p0", "p1", "p2"]
    np.testing.assert_allclose(avg.poses[:, :3, 3], base[:, :3, 3], atol=3e-5)
    np.testing.assert_allclose(avg.poses[:, :3, :3], base[:, :3, :3], atol=6e-4)  # ~5 sigma
    # RMS distance of an isotropic 3-D Gaussian is sqrt(3) sigma
    np.testing.assert_allclose(avg.jitter_trans_rms, np.sqrt(3) * 1e-4, rtol=0.15)
    np.testing.assert_allclose(avg.jitter_rot_rms, np.sqrt(3) * np.deg2rad(0.1), rtol=0.15)
    s = avg.summary()
    assert s["n_samples"] == 600 and s["jitter_trans_rms_mm"] == pytest.approx(0.173, rel=0.15)


def test_pose_csv_round_trip_and_units(tmp_path):
    rng = np.random.default_rng(22)
    P = pose_from_rt(Rotation.random(6, random_state=1).as_matrix(), rng.normal(size=(6, 3)))
    D = pose_from_rt(Rotation.random(6, random_state=2).as_matrix(), rng.normal(size=(6, 3)))
    f = write_poses_csv(tmp_path / "pairs.csv", P, D, group=list("aabbcc"))
    t = read_poses_csv(f)
    np.testing.assert_allclose(t.poses, P, atol=1e-14)
    np.testing.assert_allclose(t.reference, D, atol=1e-14)
    assert t.group.tolist() == list("aabbcc") and t.has_orientation and t.reference_has_orientation
    # mm + degrees rotation vectors, and scalar-first quaternions
    q = Rotation.from_matrix(P[:, :3, :3]).as_quat(scalar_first=True)
    lines = ["X_mm,Y_mm,Z_mm,qw,qx,qy,qz,ref_x,ref_y,ref_z,ref_rx_deg,ref_ry_deg,ref_rz_deg,note"]
    rv = np.rad2deg(Rotation.from_matrix(D[:, :3, :3]).as_rotvec())
    for k in range(6):
        vals = list(P[k, :3, 3] * 1e3) + list(q[k]) + list(D[k, :3, 3]) + list(rv[k])
        lines.append(",".join(repr(float(v)) for v in vals) + ",free text")
    g = tmp_path / "mixed.csv"
    g.write_text("# comment line\n" + "\n".join(lines) + "\n")
    t2 = read_poses_csv(g)
    np.testing.assert_allclose(t2.poses, P, atol=1e-12)
    np.testing.assert_allclose(t2.reference, D, atol=1e-12)
    # position only
    h = tmp_path / "pos.csv"
    h.write_text("x,y,z\n1,2,3\n4,5,6\n")
    t3 = read_poses_csv(h, length_unit="mm")
    assert not t3.has_orientation and t3.reference is None
    np.testing.assert_allclose(t3.poses[1, :3, 3], [4e-3, 5e-3, 6e-3])
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="x, y, z"):
        read_poses_csv(bad)
    bad.write_text("x,y,z\n1,oops,3\n")
    with pytest.raises(ValueError, match="number"):
        read_poses_csv(bad)
