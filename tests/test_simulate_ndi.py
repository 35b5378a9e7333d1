"""'openemt simulate --reference optical --format ndi' and openemt.io.write_ndi_tsv: a simulated
NDI Toolbox session that 'openemt import ndi' reads back exactly (to the file's precision)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from openemt.cli import main
from openemt.evaluate import pose_error_magnitudes
from openemt.geometry import invert
from openemt.io import read_ndi_tsv, write_ndi_tsv
from openemt.simulate import simulate_ndi_session
from openemt.simulate._hybrid import NDI_EM_LABEL, NDI_OPTICAL_LABEL


def test_write_ndi_tsv_round_trips_poses_and_missing_rows(tmp_path):
    tools, truth = simulate_ndi_session(30, seed=4)
    em = tools[NDI_EM_LABEL].copy()
    em[5] = np.nan                                   # not seen: written as Missing
    path = write_ndi_tsv(tmp_path / "s.tsv", {NDI_EM_LABEL: em,
                                              NDI_OPTICAL_LABEL: tools[NDI_OPTICAL_LABEL]},
                         first_frame=100)
    rec = read_ndi_tsv(path)
    a, b = rec.tool("10"), rec.tool("Port 1")
    assert a.skipped == {"Missing": 1} and len(a.poses) == 29 and len(b.poses) == 30
    assert a.frame.tolist() == [100 + k for k in range(30) if k != 5]
    t, r = pose_error_magnitudes(a.poses, np.delete(em, 5, axis=0))
    assert t.max() < 1e-7 and r.max() < 1e-5      # 0.1 um and 1e-6 quaternion digits
    # the optical marker sees the sensor through the true X and Y (plus its noise)
    t, _ = pose_error_magnitudes(truth["Y"] @ b.poses @ invert(truth["X"]), truth["poses"])
    assert 0 < np.sqrt(np.mean(t ** 2)) < 1e-3


def test_write_ndi_tsv_refuses_mismatched_tools(tmp_path):
    P = np.tile(np.eye(4), (3, 1, 1))
    with pytest.raises(ValueError, match=r"expected poses of shape \(3, 4, 4\)"):
        write_ndi_tsv(tmp_path / "x.tsv", {"Port 1": P, "Port 2": P[:2]})
    with pytest.raises(ValueError, match="expected a port label"):
        write_ndi_tsv(tmp_path / "x.tsv", {"Tool A": P})
    assert not (tmp_path / "x.tsv").exists()


def test_simulate_format_ndi_command(tmp_path, capsys):
    out = tmp_path / "session.tsv"
    argv = ["simulate", "--reference", "optical", "--format", "ndi", "--n-poses", "25",
            "--seed", "7", "-o", str(out), "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["n_samples"] == 25 and summary["tools"] == [NDI_EM_LABEL, NDI_OPTICAL_LABEL]
    _, truth = simulate_ndi_session(25, seed=7)
    np.testing.assert_allclose(summary["truth"]["X"], truth["X"])
    rec = read_ndi_tsv(out)
    assert [len(t.poses) for t in rec.tools] == [25, 25] and not rec.bad_rows
    # import ndi reads both tools of the export
    assert main(["import", "ndi", str(out), "--tool", "Port 1", "-o",
                 str(tmp_path / "p.h5"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n_samples"] == 25


@pytest.mark.parametrize("extra, got", [([], "no --reference"),
                                        (["--reference", "robot"], "--reference robot"),
                                        (["--reference", "optical", "--snr-db", "40"],
                                         "--snr-db")])
def test_simulate_format_ndi_bad_options(tmp_path, capsys, extra, got):
    out = tmp_path / "s.tsv"
    assert main(["simulate", "--format", "ndi", *extra, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: expected --format ndi")
    assert err.endswith(f"got {got}")
    assert list(tmp_path.iterdir()) == []
