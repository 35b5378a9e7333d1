"""Long commands say what they do before they do it: stage lines on stderr (plain lines, also
when stderr is not a terminal and no bar is drawn), the compile notice exactly when the kernels'
cache is cold, nothing with --quiet."""

import json

import pytest

from openemt._compile_notice import cold_kernels
from openemt.cli import main


def _lines(err):
    return [s for s in err.splitlines() if s.strip()]


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("progress")
    assert main(["simulate", "--preset", "concentric", "--pattern", "md", "--snr-db", "80",
                 "--seed", "2", "-o", str(d / "sim.h5"), "--truth-calibration",
                 str(d / "truth.json"), "--quiet"]) == 0
    return d


def test_calibrate_stage_lines_and_compile_notice(sim, tmp_path, capsys):
    cold = cold_kernels()
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(sim / "sim.h5"), "--from", str(sim / "truth.json"),
                 "--mode", "XYZ", "-o", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    summary = json.loads(cap.out)
    assert summary["mode"] == "XYZ"
    lines = _lines(cap.err)
    notice = [s for s in lines if s.startswith("compiling ")]
    assert notice == ([f"compiling {len(cold)} solver kernels (first run only) ..."] if cold
                      else [])
    # the kernels it announces are the ones it compiles: the next run is silent about them
    assert cold_kernels() == []
    stages = [s for s in lines if s.endswith(" ...")]
    assert stages == [f"fitting mode XYZ from {sim / 'truth.json'} ...",
                      (f"fitting the output correction on {summary['num_points']} rows "
                       "(lm poses) ...")]
    # each stage line comes before the results it announces
    assert lines.index(stages[-1]) < lines.index(next(s for s in lines if s.startswith("XYZ:")))


def test_bad_input_is_still_one_line(sim, tmp_path, capsys):
    # stage lines come after the inputs are read: a refused input is the error line alone
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    for argv in (["--from", str(bad)],                                  # unreadable start
                 ["--from", str(sim / "truth.json"), "--mode", "trans_only"],  # no rows
                 ["--from", str(sim / "truth.json"), "--optimize", "se_fix",
                  "--freeze", "se_fix"]):                               # nothing left free
        assert main(["calibrate", str(sim / "sim.h5"), *argv, "-o",
                     str(tmp_path / "c.json")]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err


def test_report_stage_lines(sim, tmp_path, capsys):
    out = tmp_path / "r.html"
    assert main(["report", str(sim / "sim.h5"), "--calibration", str(sim / "truth.json"),
                 "-o", str(out)]) == 0
    lines = _lines(capsys.readouterr().err)
    assert f"solving and scoring the 852 rows of sim.h5 with {sim / 'truth.json'}, drawing the " \
           "figures ..." in lines
    assert lines.index(f"writing {out} ...") < lines.index(
        next(s for s in lines if s.startswith("report: ")))


@pytest.mark.parametrize("argv", [
    ["calibrate", "{sim}/sim.h5", "--from", "{sim}/truth.json", "--mode", "XYZ", "-o",
     "{tmp}/q.json"],
    ["report", "{sim}/sim.h5", "--calibration", "{sim}/truth.json", "-o", "{tmp}/q.html"],
])
def test_quiet_says_nothing(argv, sim, tmp_path, capsys):
    argv = [a.format(tmp=tmp_path, sim=sim) for a in argv]
    assert main([*argv, "--quiet"]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("given", [False, True])
def test_solve_announces_the_kernels_it_runs(given, tmp_path, capsys, monkeypatch):
    """``solve``'s compile step names the cold start's kernel where its Kim18 start is the
    invariant table's (a source with coil offsets, no concentric calibration given), which
    compiled after the notice before; not where a concentric calibration starts it."""
    import openemt._compile_notice as notice

    assert main(["simulate", "--preset", "dipole-approx", "--pattern", "ld", "--seed", "3",
                 "-o", str(tmp_path / "d.h5"), "--truth-calibration", str(tmp_path / "t.json"),
                 "--quiet"]) == 0
    calls = []
    monkeypatch.setattr(notice, "announce_compile",
                        lambda out, what, *, kernels: calls.append((what, tuple(kernels))))
    start = []
    if given:                               # the same source with its coil offsets dropped
        import numpy as np

        from openemt.io import read_calibration, write_calibration

        cal = read_calibration(tmp_path / "t.json")
        write_calibration(cal.replace(model=cal.model.replace(
            L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))), tmp_path / "c.json")
        start = ["--concentric-calibration", str(tmp_path / "c.json")]
    assert main(["solve", str(tmp_path / "d.h5"), "--calibration", str(tmp_path / "t.json"),
                 "-o", str(tmp_path / "p.h5"), "--quiet", *start]) == 0
    table = () if given else notice.COLD_START_KERNELS
    assert calls == [("solver kernels", notice.SOLVER_KERNELS + table)]


def test_solve_of_a_6dof_board_announces_the_lm_kernels_board_form(tmp_path, monkeypatch):
    """A board read by a two-coil sensor is solved by the LM kernels' board specialisation:
    the notice names it (it named the 5-DOF solver's kernels, and the LM's compiled in the
    first block)."""
    import openemt._compile_notice as notice

    assert main(["simulate", "--preset", "anser-6dof", "--reference", "robot", "--n-poses",
                 "30", "--seed", "1", "-o", str(tmp_path / "b.h5"), "--truth-calibration",
                 str(tmp_path / "t.json"), "--quiet"]) == 0
    calls = []
    monkeypatch.setattr(notice, "announce_compile",
                        lambda out, what, *, kernels: calls.append((what, tuple(kernels))))
    assert main(["solve", str(tmp_path / "b.h5"), "--calibration", str(tmp_path / "t.json"),
                 "-o", str(tmp_path / "p.h5"), "--quiet"]) == 0
    assert calls == [("finite-coil kernels", notice.BOARD_LM_KERNELS)]
