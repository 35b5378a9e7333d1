"""``openemt import ilemt`` and ``openemt info`` run in-process."""

from __future__ import annotations

import json

import numpy as np
import pytest

from openemt.io import import_ilemt_folder, read_calibration, read_dataset, write_calibration


def test_import_ilemt_json_and_round_trip(run_cli, ilemt_dir, tmp_path):
    out = tmp_path / "cal_9_15.h5"
    code, stdout, _ = run_cli("import", "ilemt", ilemt_dir, "-o", out, "--json", "--quiet")
    assert code == 0
    s = json.loads(stdout)
    assert s["n_samples"] == 8033 and s["n_source"] == 3 and s["n_sensor"] == 3
    assert s["path"] == str(out) and len(s["files"]) == 21
    assert s["files"]["soYoutZup_seYoutZup_sweep.dat"] == 973
    assert s["files"]["soYoutZup_seYoutZup_mdtrans.dat"] == 30
    assert s["signs_from"] == "local_cal_options.m" and s["compensate_stage"] is True
    ds = read_dataset(out)
    ref = import_ilemt_folder(ilemt_dir)
    np.testing.assert_array_equal(ds.couplings, ref.couplings)
    np.testing.assert_array_equal(ds.stage, ref.stage)
    np.testing.assert_array_equal(ds.source_signs, ref.source_signs)
    np.testing.assert_array_equal(ds.extra["couplings_lr"], ref.extra["couplings_lr"])
    assert ds.files == ref.files and ds.meta == ref.meta

    code, stdout, _ = run_cli("info", out, "--json")
    info = json.loads(stdout)
    assert code == 0 and info["kind"] == "dataset" and info["n_samples"] == 8033
    assert info["patterns"]["md"] == 6 * 142 and info["source"] == "CMU"
    assert info["complex"] is True and info["extra"] == ["couplings_lr"]


def test_import_options(run_cli, ilemt_dir, tmp_path):
    out = tmp_path / "md.h5"
    code, stdout, err = run_cli("import", "ilemt", ilemt_dir, "-o", out, "--patterns", "md",
                            "--source-signs", "XinYup=-1,1,1", "--no-compensate", "--json")
    assert code == 0 and "imported 852 rows" in err
    ds = read_dataset(out)
    s = json.loads(stdout)
    assert s["source_signs"] == [["XinYup", [-1, 1, 1]]] and s["compensate_stage"] is False
    flipped = {ds.files[i] for i in np.unique(ds.file_index[ds.source_signs[:, 0] == -1])}
    assert flipped == {"soXinYup_seYoutZup_md.dat"}        # the CLI rule replaced the file's
    np.testing.assert_array_equal(ds.stage, ds.stage_logged)


def test_info_on_calibrations(run_cli, ilemt_dir, tmp_path):
    code, stdout, _ = run_cli("info", ilemt_dir / "output" / "XYZ_hr_cal.mat", "--json")
    info = json.loads(stdout)
    assert code == 0 and info["kind"] == "calibration" and info["mode"] == "XYZ"
    assert info["linear_correction"] is True and info["stats"]["num_points"] == 426
    write_calibration(read_calibration(ilemt_dir / "output" / "XYZ_concentric_hr_cal.mat"),
                      tmp_path / "c.json")
    code, stdout, _ = run_cli("info", tmp_path / "c.json", "--json")
    info = json.loads(stdout)
    assert code == 0 and info["concentric"] is True and info["mode"] == "XYZ_concentric"


@pytest.mark.parametrize("argv, match", [
    (["--source-signs", "abc"], "expected a sign rule 'REGEX=sx,sy,sz'"),
    (["--source-signs", "md=1,1,2"], "expected a sign rule"),
    (["--patterns", "zz"], "got none"),
])
def test_import_bad_input_exit_2_without_output(run_cli, ilemt_dir, tmp_path, argv, match):
    out = tmp_path / "o.h5"
    code, _, err = run_cli("import", "ilemt", ilemt_dir, "-o", out, *argv)
    assert code == 2 and err.startswith("error: ") and match in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_import_corrupt_folder_exit_2(run_cli, tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    (src / "soYoutZup_seYoutZup_md.dat").write_text("1\t2\t3\n")
    out = tmp_path / "o.h5"
    code, _, err = run_cli("import", "ilemt", src, "-o", out)
    assert code == 2 and "soYoutZup_seYoutZup_md.dat: line 1: expected 24 fields, got 3" in err
    assert not out.exists()
    code, _, err = run_cli("import", "ilemt", tmp_path / "missing", "-o", out)
    assert code == 2 and "missing folder" in err and not out.exists()


def test_info_bad_input(run_cli, tmp_path):
    code, _, err = run_cli("info", tmp_path / "none.h5")
    assert code == 2 and "missing file" in err
    (tmp_path / "x.h5").write_text("nope")
    code, _, err = run_cli("info", tmp_path / "x.h5")
    assert code == 2 and "expected a readable openemt HDF5 file, got x.h5" in err
    (tmp_path / "x.txt").write_text("nope")
    code, _, err = run_cli("info", tmp_path / "x.txt")
    assert code == 2 and "expected a file openemt writes (dataset or poses .h5" in err
