"""The README's shell examples run as written, top to bottom, in a scratch folder.

Every fenced ``bash`` block runs in order in one empty folder (only ``src`` links to the
clone's ``src``, as in a fresh clone's root), with ``set -e`` and the test's environment
(the venv's ``bin`` first on PATH), so every file an example reads must be made by an earlier
example. Blocks marked ``<!-- test-command -->`` (CI's own command) or
``<!-- not-run: REASON -->`` (set-up, hardware) are skipped. The live commands carry a
``--duration`` so they end; they serve OpenIGTLink on Slicer's port 18944, so that port must be
free while this test runs.
"""

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _readme_blocks import README, readme_blocks

ROOT = README.parent
SKIPPED = ("test-command", "not-run:")


def _runnable():
    return [code for marker, code in readme_blocks("bash")
            if not marker.startswith(SKIPPED)]


def test_readme_marks_only_set_up_and_hardware_blocks_as_not_run():
    skipped = [(m, c) for m, c in readme_blocks("bash") if m.startswith(SKIPPED)]
    reasons = sorted(m for m, _ in skipped)
    assert reasons == ["not-run: needs a sound card or an ADC",
                       "not-run: set-up, run once by hand from the clone's root",
                       "test-command"]
    hardware = next(c for m, c in skipped if "sound card" in m)
    assert all(any(f"--source {s}" in ln for s in ("sound", "serial:", "tcp://"))
               or ln.strip() == "openemt devices" for ln in hardware.splitlines() if ln.strip())
    # the live examples end by themselves
    for code in _runnable():
        for line in code.replace("\\\n", " ").splitlines():
            if line.strip().startswith("openemt track"):
                assert "--duration" in line, line


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_readme_shell_blocks_run_as_written(tmp_path):
    blocks = _runnable()
    assert any("openemt import ilemt" in b for b in blocks), "the 'Using it' block went missing"
    for _ in range(30):  # another run of this test may hold Slicer's port for a few seconds
        if _port_free(18944):
            break
        time.sleep(1)
    else:
        pytest.fail("port 18944 (OpenIGTLink) is busy: the README's live examples serve on it")
    (tmp_path / "src").symlink_to(ROOT / "src", target_is_directory=True)
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    script = "\n".join(["set -eo pipefail",
                        "trap 'echo \"README command failed (status $?): $BASH_COMMAND\" >&2' ERR",
                        *blocks])
    t0 = time.perf_counter()
    proc = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=900, check=False)
    elapsed = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr[-4000:]
    print(f"README shell blocks: {elapsed:.1f} s")
    # what the examples promise is there
    for name in ("poses.h5", "report.html", "board.html", "corrected.csv", "my-tracker.toml"):
        assert (tmp_path / name).stat().st_size > 0, name
    # the solve example picks the hemisphere per source fixture and explains its failed rows
    assert "hemisphere per source fixture" in proc.stderr
