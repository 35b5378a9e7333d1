"""NDI Toolbox exports in the layout real files have: the full port label in the header and
in every row, sentinel-filled non-OK rows, truncated rows, CRLF, BOM, trailing tabs; and
``openemt import ndi|poses`` into pose datasets."""

import json

import numpy as np
import pytest
from _ndi_export import EM, EM2, OPT, SENT
from _ndi_export import write_export as _write
from scipy.spatial.transform import Rotation

from openemt.cli import main
from openemt.geometry import pose_from_rt
from openemt.io import import_ndi, read_ndi_tsv, read_pose_dataset, read_poses_csv


def _poses(n, seed):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    return pose_from_rt(R, rng.uniform(-0.2, 0.2, (n, 3)) + [0, 0, -0.3])


def test_three_tools_labels_states_and_truncated_row(tmp_path):
    n = 12
    P = [_poses(n, s) for s in (1, 2, 3)]
    f = tmp_path / "aurora_polaris.tsv"
    states = {(2, 0): "Missing", (4, 2): "Too Few Markers", (5, 2): "Too Few Markers",
              (6, 1): "Missing"}
    _write(f, [EM, EM2, OPT], P, states=states, truncate=True, crlf=True, bom=True,
           trailing=True)
    rec = read_ndi_tsv(f)
    assert [t.port for t in rec.tools] == ["10", "11", "1"]
    assert rec.tools[0].label == EM and rec.tools[2].label == OPT  # double spaces kept
    # the truncated last row (line n + 1) is reported, not used
    assert [b["line"] for b in rec.bad_rows] == [n + 1]
    assert rec.bad_rows[0]["reason"] == "truncated row"
    em, opt = rec.tool("10"), rec.tool(1)
    assert rec.tool(EM) is em and rec.tool(" ".join(OPT.split()).upper()) is opt
    assert rec.tool("Port 11") is rec.tools[1]
    assert em.n_rows == n - 1 and em.skipped == {"Missing": 1}
    assert opt.skipped == {"Too Few Markers": 2}
    assert rec.tools[1].skipped == {"Missing": 1}
    keep = [k for k in range(n - 1) if k != 2]
    np.testing.assert_array_equal(em.frame, 1000 + np.array(keep))
    np.testing.assert_array_equal(em.line, np.array(keep) + 2)
    np.testing.assert_allclose(em.poses[:, :3, 3], P[0][keep, :3, 3], atol=1e-7)
    np.testing.assert_allclose(em.poses[:, :3, :3], P[0][keep, :3, :3], atol=5e-6)
    np.testing.assert_allclose(em.error, 0.1234e-3)
    with pytest.raises(ValueError, match="expected a tool port or label"):
        rec.tool("12")
    s = rec.summary()
    assert s["n_bad_rows"] == 1 and s["bad_lines"] == [n + 1]


def test_wrong_field_counts_sentinels_and_ambiguous_port(tmp_path):
    P = [_poses(6, 4)]
    f = tmp_path / "one.tsv"
    _write(f, [EM], P)
    lines = f.read_text().splitlines()
    lines[3] = lines[3] + "\t7\t8"  # too many fields
    lines[4] = "\t".join(lines[4].split("\t")[:-3])  # too few
    # an OK row whose pose holds the sentinel: skipped, not read as a pose
    cells = lines[5].split("\t")
    cells[5] = SENT
    lines[5] = "\t".join(cells)
    f.write_text("\n".join(lines) + "\n")
    rec = read_ndi_tsv(f)
    assert [(b["line"], b["fields"], b["expected"]) for b in rec.bad_rows] == [
        (4, 16, 14), (5, 11, 14)]
    t = rec.tools[0]
    assert t.skipped == {"OK without a pose": 1} and len(t.poses) == 3
    # two channels on one port: the port number is ambiguous, the label is not
    g = tmp_path / "two.tsv"
    ch1 = EM.replace("Channel:0", "Channel:1")
    _write(g, [EM, ch1], [P[0], P[0]])
    rec2 = read_ndi_tsv(g)
    with pytest.raises(KeyError, match="full label"):
        rec2.tool("10")
    assert rec2.tool(ch1).label == ch1


def test_import_ndi_cli_average_static_and_tool_selection(tmp_path, capsys):
    rng = np.random.default_rng(7)
    truth = _poses(3, 9)
    files = []
    for i in range(3):  # three static recordings, given out of name order
        noisy = []
        for _ in range(30):
            dR = Rotation.from_rotvec(np.deg2rad(0.05) * rng.standard_normal(3)).as_matrix()
            noisy.append(pose_from_rt(truth[i, :3, :3] @ dR,
                                      truth[i, :3, 3] + 1e-4 * rng.standard_normal(3)))
        f = tmp_path / f"static_{2 - i}.tsv"
        _write(f, [EM, OPT], [np.array(noisy), np.array(noisy)],
               states={(3, 0): "Missing", (5, 1): "Too Few Markers"}, truncate=(i == 1))
        files.append(f)
    out = tmp_path / "em.h5"
    rc = main(["import", "ndi", *map(str, files), "-o", str(out), "--tool", "10",
               "--average-static", "--json"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    s = json.loads(cap.out)
    assert s["n_samples"] == 3 and s["skipped"] == {"Missing": 3}
    assert s["n_bad_rows"] == 1 and s["files"][1]["bad_lines"] == [31]
    assert [f["label"] for f in s["files"]] == [EM] * 3
    assert all(0.1 < f["jitter_trans_sd_mm"] < 0.25 for f in s["files"])
    ds = read_pose_dataset(out)
    assert list(ds.files) == [f.name for f in files]
    np.testing.assert_allclose(ds.poses[:, :3, 3], truth[:, :3, 3], atol=1e-4)
    assert ds.extra["n_averaged"].tolist() == [29, 28, 29]
    # all rows, frames kept
    out2 = tmp_path / "opt.h5"
    assert main(["import", "ndi", str(files[0]), "-o", str(out2), "--tool", OPT, "--json"]) == 0
    s2 = json.loads(capsys.readouterr().out)
    assert s2["skipped"] == {"Too Few Markers": 1}
    ds2 = read_pose_dataset(out2)
    assert ds2.n_samples == 29 and 1005 not in ds2.extra["frame"]
    # several tools and no --tool; an unknown tool: one error line, exit 2, no output
    out3 = tmp_path / "x.h5"
    assert main(["import", "ndi", str(files[0]), "-o", str(out3)]) == 2
    assert "expected --tool" in capsys.readouterr().err
    assert main(["import", "ndi", str(files[0]), "-o", str(out3), "--tool", "12"]) == 2
    assert "error: expected a tool port or label" in capsys.readouterr().err
    assert not out3.exists()
    ds3, _ = import_ndi([files[2]], tool="Port 1")
    assert ds3.n_samples == 29


def test_import_poses_csv_counts_truncated_and_missing_rows(tmp_path, capsys):
    f = tmp_path / "robot.csv"
    f.write_text("\ufeffframe,x_mm,y_mm,z_mm,qw,qx,qy,qz\r\n"
                 "1,1,2,3,1,0,0,0\r\n"
                 "2,4,5,6,1,0,0,0\r\n"
                 "3,7,,9,1,0,0,0\r\n"
                 "4,7,8,9,1,0,0,0,\r\n"
                 "5,7,8")
    t = read_poses_csv(f)
    assert t.bad_lines == (6,) and t.nonfinite_lines == (4,)
    assert t.frame.tolist() == [1, 2, 3, 4, -1]  # the truncated row is read as empty
    out = tmp_path / "robot.h5"
    assert main(["import", "poses", str(f), "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["n_samples"] == 3 and s["n_bad_rows"] == 1 and s["n_nonfinite_rows"] == 1
    assert "lines 6" in cap.err and "lines 4" in cap.err
    ds = read_pose_dataset(out)
    assert ds.extra["frame"].tolist() == [1, 2, 4]
    np.testing.assert_allclose(ds.poses[2, :3, 3], [7e-3, 8e-3, 9e-3])


def test_last_row_cut_at_every_position_is_reported_or_complete(tmp_path):
    P = [_poses(4, 12), _poses(4, 13)]
    f = tmp_path / "cut.tsv"
    _write(f, [EM, OPT], P)
    lines = f.read_text().splitlines()
    last = lines[-1]
    for cut in range(1, len(last)):
        f.write_text("\n".join(lines[:-1] + [last[:cut]]))
        rec = read_ndi_tsv(f)
        em = rec.tool(10)
        np.testing.assert_allclose(em.poses[:3, :3, 3], P[0][:3, :3, 3], atol=1e-7)
        if rec.bad_rows:
            assert [b["line"] for b in rec.bad_rows] == [5] and len(em.poses) == 3
        else:  # only the marker count of the last tool was cut: every pose field is intact
            assert last[cut:].strip().isdigit()
            np.testing.assert_allclose(rec.tool(1).poses[3, :3, 3], P[1][3, :3, 3], atol=1e-7)
