"""``collect --follow-reference`` against a reference server built on the OpenIGTLink C++
library (Debian's libopenigtlink-dev 1.11, header version 1; source
tests/cpp/igtl_reference_server.cxx), then ``calibrate --mode reference``: the held-out error
is within 1.25 times that of the simulated path (``--simulate-reference robot``, the same
poses and seed).

Skipped, with the reason, where no C++ compiler or no OpenIGTLink library is found."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
from _igtl_cpp import build_cpp

from openemt.cli import main
from openemt.collect import simulated_motion, spare_poses
from openemt.geometry import pose_from_vector
from openemt.io import read_dataset

N, SEED, SPEED, RATE, LATENCY = 16, 2, 4.0, 250.0, 0.03


@pytest.fixture(scope="module")
def cpp_server(tmp_path_factory):
    """The C++ reference server, compiled against the OpenIGTLink library found here."""
    return build_cpp("igtl_reference_server", tmp_path_factory.mktemp("cpp"))


def _motion_file(path, motion, rng):
    """The robot's reported tool poses at ``RATE`` Hz of motion time (each the pose of
    ``LATENCY`` earlier with the stream's per-message noise, as the Python simulated server
    sends them), in the server's format: ``t x y z`` (mm) and the rotation row by row."""
    t = np.arange(0.0, motion.hold_ends[-1] + 0.5, 1.0 / RATE)
    B = motion.reference_poses(t - LATENCY)
    v = np.concatenate([motion.jitter_trans / np.sqrt(3) * rng.standard_normal((len(t), 3)),
                        motion.jitter_rot / np.sqrt(3) * rng.standard_normal((len(t), 3))], 1)
    B = B @ pose_from_vector(v)
    rows = np.column_stack([t, 1e3 * B[:, :3, 3], B[:, :3, :3].reshape(-1, 9)])
    np.savetxt(path, rows, fmt="%.9g", header="t x_mm y_mm z_mm r00 r01 r02 r10 r11 r12 r20 "
               "r21 r22")


def _run_json(args, capsys) -> dict:
    capsys.readouterr()
    assert main(args) == 0
    return json.loads(capsys.readouterr().out)


def _collect_and_calibrate(args, out, capsys):
    c = _run_json(["collect", "--source", "sim", "--n-poses", str(N), "--seed", str(SEED),
                   "--sim-speed", str(SPEED), "--duration", "120", "-o", str(out), "--json",
                   *args], capsys)
    k = _run_json(["calibrate", str(out), "--mode", "reference", "--holdout", "0.2",
                   "--seed", "0", "-o", str(out.with_suffix(".json")), "--json"], capsys)
    return c, k


def test_follow_a_cpp_reference_server_calibrates_like_the_simulated_path(cpp_server, tmp_path,
                                                                          capsys):
    motion = simulated_motion("robot", N, spare=spare_poses(N) + 20, seed=SEED)
    _motion_file(tmp_path / "motion.txt", motion, np.random.default_rng([SEED, 21]))
    proc = subprocess.Popen([str(cpp_server), str(tmp_path / "motion.txt"), "RobotToBase", "0",
                             str(SPEED), "2", "60"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline().split()
        assert first[:1] == ["PORT"], (first, proc.stderr.read() if proc.poll() else "")
        url = f"igtl://127.0.0.1:{first[1]}/RobotToBase"
        cpp, cpp_cal = _collect_and_calibrate(["--follow-reference", "--reference", url],
                                              tmp_path / "cpp.h5", capsys)
    finally:
        proc.terminate()
        out, err = proc.communicate(timeout=10)
    sim, sim_cal = _collect_and_calibrate(["--simulate-reference", "robot"], tmp_path / "sim.h5",
                                          capsys)
    for c, h5 in ((cpp, "cpp.h5"), (sim, "sim.h5")):     # every requested pose written
        assert c["n_poses"] == N and c["ended_by"] == "n_poses", c
        assert read_dataset(tmp_path / h5).n_samples == N
    # the C++ library's version-1 TRANSFORMs, read whole, with time stamps the offset
    # estimate pairs (the median angle between the paired rotations: the stream's noise)
    assert cpp["reference_poses_received"] > 0 and not cpp["reference_dropped"], cpp
    assert cpp["pairing"]["ok"] and cpp["pairing"]["angle_diff_deg_median"] < 0.1, cpp
    a, b = cpp_cal["holdout"]["trans_rms_mm"], sim_cal["holdout"]["trans_rms_mm"]
    print(f"held-out position RMS: C++ reference {a:.4f} mm, simulated {b:.4f} mm")
    assert np.isfinite(a) and a <= 1.25 * b
