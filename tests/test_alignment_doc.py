"""docs/alignment.md: the end-to-end commands run as written on simulated NDI exports (an
Aurora sensor with a field distortion and an optical marker in one session, real layout)."""

import json
import re
import shlex
from pathlib import Path

import numpy as np
from _ndi_export import EM, OPT, write_export

from openemt.bench._hybrid import simulate_hybrid
from openemt.cli import main
from openemt.evaluate import pose_error_magnitudes
from openemt.geometry import invert, pose_from_rt
from openemt.io import read_pose_dataset, read_poses_csv

DOC = Path(__file__).resolve().parents[1] / "docs" / "alignment.md"


def _commands():
    text = DOC.read_text()
    block = re.search(r"<!-- end-to-end -->\s*```bash\n(.*?)```", text, flags=re.DOTALL)
    assert block, "docs/alignment.md lost its end-to-end block"
    return [shlex.split(ln) for ln in block.group(1).splitlines() if ln.strip()]


def _session(path, n, X, Y, rng, first_frame):
    sim = simulate_hybrid(n, X, Y, rng)
    states = {(3, 1): "Too Few Markers", (8, 0): "Missing", (9, 1): "Missing"}
    write_export(path, [EM, OPT], [sim["em"], sim["optical"]], states=states, truncate=True,
                 first_frame=first_frame)
    return sim


def test_alignment_doc_commands_run_end_to_end(tmp_path, monkeypatch, capsys):
    rng = np.random.default_rng(11)
    X = pose_from_rt(np.eye(3)[[1, 2, 0]], [0.01, 0.02, -0.03])
    Y = pose_from_rt(np.eye(3)[[2, 0, 1]], [0.3, -0.5, 0.8])
    _session(tmp_path / "session.tsv", 160, X, Y, rng, 1000)
    new = _session(tmp_path / "session_new.tsv", 80, X, Y, rng, 5000)
    monkeypatch.chdir(tmp_path)
    outputs = []
    for argv in _commands():
        assert argv[0] == "openemt"
        rc = main(argv[1:])
        cap = capsys.readouterr()
        assert rc == 0, f"{' '.join(argv)}\n{cap.err}"
        outputs.append(json.loads(cap.out) if "--json" in argv else None)
    imp_em, imp_opt, align, fit, imp_new, apply_h5 = outputs[:6]
    # 160 rows, the last one cut short; missing rows skipped and counted per state
    assert imp_em["n_samples"] == 158 and imp_em["skipped"] == {"Missing": 1}
    assert imp_opt["skipped"] == {"Too Few Markers": 1, "Missing": 1}
    assert imp_em["files"][0]["bad_lines"] == [161]
    # pairs by frame: 156 frames have both tools
    assert align["n"] == 156 and align["n_unmatched_measured"] == 2
    assert align["held_out"]["trans_rms_mm"] < 1.5 * align["residual_trans_rms_mm"]
    # the correction removes most of the 3 mm distortion on pairs it did not see
    ho = fit["held_out"]
    assert ho["corrected"]["trans_rms_mm"] < 0.4 * ho["uncorrected"]["trans_rms_mm"]
    assert fit["method"] != "none" and not fit["worse_than_none"]
    assert imp_new["n_samples"] == 78
    assert apply_h5["orientation_corrected"]
    # the corrected new recording against the optical poses mapped with the fitted X, Y
    keep = np.setdiff1d(np.arange(79), [8])
    ref = np.array(align["Y"]) @ new["optical"][keep] @ invert(np.array(align["X"]))
    before = pose_error_magnitudes(read_pose_dataset("aurora_new.h5").poses, ref)[0]
    after = pose_error_magnitudes(read_pose_dataset("aurora_new_corrected.h5").poses, ref)[0]
    assert np.sqrt(np.mean(after ** 2)) < 0.4 * np.sqrt(np.mean(before ** 2))
    csv = read_poses_csv("aurora_new_corrected.csv")
    np.testing.assert_allclose(csv.poses, read_pose_dataset("aurora_new_corrected.h5").poses,
                               atol=1e-12)
    assert csv.frame[0] == 5000
