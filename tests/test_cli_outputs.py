"""No command overwrites its input; killed runs leave no partial or orphaned files."""

import os
import signal
import subprocess
import sys

import pytest

from openemt._atomic import check_output_path, remove_stale_temporaries
from openemt._errors import InputError
from openemt.cli import main
from openemt.io import atomic_path


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("ds")
    out = d / "sim.h5"
    truth = d / "truth.json"
    assert main(["simulate", "--preset", "dipole-approx", "--pattern", "md", "--seed", "1",
                 "-o", str(out), "--truth-calibration", str(truth), "--quiet"]) == 0
    return out, truth


def _unchanged(path, before):
    return path.read_bytes() == before


def test_solve_refuses_to_overwrite_its_dataset(small_dataset, capsys, tmp_path):
    data, cal = small_dataset
    before = data.read_bytes()
    for target in (str(data), str(data.parent / ".." / data.parent.name / data.name)):
        assert main(["solve", str(data), "--calibration", str(cal), "-o", target]) == 2
        err = capsys.readouterr().err
        assert "expected an output path different from the input" in err
        assert err.count("error:") == 1
    link = tmp_path / "link.h5"
    link.symlink_to(data)
    hard = tmp_path / "hard.h5"
    os.link(data, hard)
    for target in (link, hard):
        assert main(["solve", str(data), "--calibration", str(cal), "-o", str(target)]) == 2
    assert _unchanged(data, before)


def test_outputs_inside_an_input_folder_are_refused(ilemt_dir, tmp_path, capsys):
    target = ilemt_dir / "soYoutZup_seYoutZup_md.dat"
    before = target.read_bytes()
    assert main(["import", "ilemt", str(ilemt_dir), "-o", str(target)]) == 2
    assert main(["import", "ilemt", str(ilemt_dir), "-o", str(ilemt_dir / "new.h5")]) == 2
    assert "outside the input folder" in capsys.readouterr().err
    assert _unchanged(target, before)
    assert not (ilemt_dir / "new.h5").exists()


def test_check_output_path_allows_distinct_files(tmp_path):
    a = tmp_path / "a.h5"
    a.write_text("x")
    check_output_path(tmp_path / "b.h5", [a, tmp_path / "missing"])
    with pytest.raises(InputError):
        check_output_path(a, [a])


def test_stale_temporaries_of_dead_runs_are_removed(tmp_path):
    # temporaries named as by earlier versions (.<target>.openemt-<pid>.<random>.<suffix>):
    # those of dead runs are removed by the next run writing in the folder, whatever their target
    target = tmp_path / "out.h5"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale = tmp_path / f".out.h5.openemt-{dead}.abcd1234.h5"
    live = tmp_path / f".out.h5.openemt-{os.getpid()}.abcd1234.h5"
    other = tmp_path / f".other.h5.openemt-{dead}.abcd1234.h5"
    for f in (stale, live, other):
        f.write_text("partial")
    assert sorted(remove_stale_temporaries(target)) == sorted([stale, other])
    with atomic_path(target, suffix=".h5") as tmp:
        tmp.write_text("done")
    assert target.read_text() == "done"
    assert live.exists() and not other.exists() and not stale.exists()


def test_sigterm_removes_the_temporary_file(tmp_path):
    out = tmp_path / "big.h5"
    code = (
        "import sys, time\n"
        "from openemt.io import atomic_path\n"
        "import openemt.cli as cli, signal\n"
        "signal.signal(signal.SIGTERM, cli._on_sigterm)\n"
        "try:\n"
        f"    with atomic_path({str(out)!r}, suffix='.h5') as tmp:\n"
        "        tmp.write_bytes(b'x' * 1000)\n"
        "        print('writing', flush=True)\n"
        "        time.sleep(30)\n"
        "except cli.Terminated:\n"
        "    sys.exit(143)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    assert any(p.name.startswith(".openemt-") for p in tmp_path.iterdir())
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=20) == 143
    assert list(tmp_path.iterdir()) == []


def test_sigterm_ends_a_live_session_like_ctrl_c(tmp_path):
    out = tmp_path / "poses.h5"
    argv = ["track", "--source", "sim", "--duration", "60", "--no-igtl", "--log", str(out),
            "--quiet"]
    # the child says when its session has processed a first chunk (rather than the test
    # waiting a fixed time, which a loaded machine or a first numba compilation can exceed:
    # SIGTERM before the session would end the command before it has anything to log)
    code = ("from openemt.live import TrackingPipeline\n"
            "step = TrackingPipeline.step\n"
            "def announced(self):\n"
            "    out = step(self)\n"
            "    if not getattr(self, '_announced', False):\n"
            "        self._announced = True\n"
            "        print('running', flush=True)\n"
            "    return out\n"
            "TrackingPipeline.step = announced\n"
            "from openemt.cli import main\n"
            f"raise SystemExit(main({argv!r}))\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "running"
    proc.send_signal(signal.SIGTERM)
    rc = proc.wait(timeout=30)
    err = proc.stderr.read()
    assert rc == 143, err  # the session ends as after Ctrl-C: summary, complete log, 143
    assert "stopped by SIGTERM" in err or err == ""
    from openemt.live import read_track_log

    log = read_track_log(out)
    assert log.complete and log.rows > 0
    assert [p for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_bug_is_not_reported_as_bad_input(monkeypatch, capsys):
    import openemt.datasets as workflow

    def broken(options, say=None):
        raise KeyError("center")

    # the bug inside the command's workflow (the command module only registers it)
    monkeypatch.setattr(workflow, "check_datasets", broken)
    assert main(["datasets"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "KeyError" in err
    assert "this is a bug in openemt" in err
