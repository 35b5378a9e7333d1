"""``openemt demo``: the whole pipeline on the simulated tracker, end to end."""

import json

from openemt._compile_notice import COMPLEX_KERNELS, SOLVER_KERNELS, cold_kernels, dipole_kernels
from openemt.cli import main

#: what the demo announces
DEMO_KERNELS = dipole_kernels(complex_couplings=False)


def test_demo_end_to_end(tmp_path, capsys, monkeypatch):
    out = tmp_path / "demo"
    # the demo leaves the complex-coupling check out of its compile step: it never runs it
    assert set(DEMO_KERNELS) == set(SOLVER_KERNELS) - set(COMPLEX_KERNELS)

    def complex_check(*args):
        raise AssertionError("the demo ran the check of complex couplings")

    monkeypatch.setattr("openemt.solve._closed_form._complex_norms", complex_check)
    assert main(["demo", "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    summary = json.loads(cap.out)
    rows = summary["rows"]
    # it says what it does before doing it (plain lines: stderr is not a terminal here)
    err = cap.err.splitlines()
    assert err[0] == f"openemt demo: simulated 'dipole-approx' tracker -> {out}/"
    stages = [s.split(" ")[0] for s in err if s.endswith(" ...")]
    # a first run compiles the solver kernels under a line of its own, before any step
    assert stages in (["simulating", "calibrating", "fitting", "solving", "writing"],
                      ["compiling", "simulating", "calibrating", "fitting", "solving",
                       "writing"])
    assert ("compile" in summary["seconds"]) == (stages[0] == "compiling")
    # what the compile notice checks is what the demo compiled: a second run says nothing
    assert cold_kernels(DEMO_KERNELS) == []
    # every failed or surprising row says why, in the summary and on stderr
    assert rows["concentric + Kim18"]["n_invalid"] == summary["n_test"]
    assert rows["concentric + Kim18"]["reason"].startswith(
        "expected: Kim18 assumes concentric coils")
    assert rows["start (perturbed)"]["reason"].startswith("not fitted")
    assert rows["calibrated"]["reason"] is None
    why = [s.strip() for s in err if s.strip().startswith("why: ")]
    assert why == [f"why: {rows[k]['reason']}" for k in ("start (perturbed)",
                                                         "concentric + Kim18")]
    # calibration from a perturbed start recovers the accuracy of the true dipole equivalent
    cal, truth, start = rows["calibrated"], rows["truth (dipole equivalent of the finite coils)"], \
        rows["start (perturbed)"]
    assert cal["n_invalid"] == 0 and truth["n_invalid"] == 0
    assert cal["trans_rms_mm"] < 0.3 and cal["rot_rms_deg"] < 0.1
    assert cal["trans_rms_mm"] < 1.2 * truth["trans_rms_mm"]
    assert start["trans_rms_mm"] > 10 * cal["trans_rms_mm"]
    # the concentric model cannot represent the 45 mm coil offsets (MacLachlan et al. 2025, Table II: ~28 mm)
    assert rows["concentric + Kim18"]["trans_rms_mm"] > 5.0
    assert summary["n_test"] == 1896 and summary["n_calibration"] == 852
    for name in ("calibration_data.h5", "test_data.h5", "truth_calibration.json",
                 "calibration.json", "concentric_calibration.json", "report.html"):
        assert (out / name).is_file(), name
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == summary["n_figures"] >= 2
    assert "Symbols and terms" in html and "expected: Kim18 assumes concentric coils" in html


def test_demo_bad_option_exit_2(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "d"), "--snr-db", "-3"]) == 2
    assert "expected --snr-db > 0" in capsys.readouterr().err
