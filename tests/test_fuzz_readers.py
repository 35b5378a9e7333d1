"""Property-based fuzzing of every reader: mutated files are read or refused with a clear
error, never crash, hang or return non-finite values silently (bounded here; the long run is
``openemt bench fuzz``)."""

import json

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from openemt_fuzz._fuzzcases import (
    BYTE_OPS,
    JSON_OPS,
    TARGETS,
    CaseRunner,
    case_bytes,
    prepare_targets,
)

from openemt._errors import InputError
from openemt.io import read_calibration, read_dataset, write_dataset
from openemt.io._jsontext import MAX_JSON_DEPTH

ops = st.lists(st.tuples(st.sampled_from(BYTE_OPS), st.integers(0, 2**30),
                         st.integers(0, 2**30)), min_size=1, max_size=4)
json_ops = st.lists(st.tuples(st.sampled_from(JSON_OPS), st.integers(0, 2**30),
                              st.integers(0, 2**30)), min_size=0, max_size=3)


@pytest.fixture(scope="module")
def fuzz(tmp_path_factory):
    work = tmp_path_factory.mktemp("fuzz")
    targets = prepare_targets(work / "seed")
    with CaseRunner(work / "runner", time_limit=10.0) as runner:
        yield targets, runner


@pytest.mark.parametrize("name", TARGETS)
def test_seed_files_read(fuzz, name):
    targets, runner = fuzz
    assert runner.run(name, targets[name].seed).kind == "ok"


@pytest.mark.parametrize("name", TARGETS)
def test_mutated_files_are_read_or_refused_cleanly(fuzz, name):
    targets, runner = fuzz
    target = targets[name]

    @settings(max_examples=40, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(ops=ops, jops=json_ops)
    def check(ops, jops):
        outcome = runner.run(name, case_bytes(target, ops, jops if target.json else ()))
        assert outcome.kind in ("ok", "rejected"), (name, ops, jops, outcome)
        if outcome.kind == "rejected":
            assert "\n" not in outcome.message.strip() and len(outcome.message) > 15, outcome

    check()


def test_runner_reports_hangs_and_crashes_of_compiled_code(tmp_path):
    from openemt_fuzz import _fuzzcases

    with CaseRunner(tmp_path, time_limit=0.5) as runner:
        assert runner.run("ilemt_dat", b"").kind == "rejected"
    assert set(_fuzzcases.OUTCOMES) >= {"hang", "crash", "garbage", "vague"}


# ---- regression cases found by fuzzing and by hand -------------------------------------


def test_deeply_nested_calibration_json_is_refused(tmp_path):
    p = tmp_path / "cal.json"
    p.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(InputError, match=f"at most {MAX_JSON_DEPTH} levels"):
        read_calibration(p)


def test_non_utf8_calibration_json_is_refused(tmp_path):
    p = tmp_path / "cal.json"
    p.write_bytes(b'{"a": "\xff"}')
    with pytest.raises(InputError, match="not UTF-8 at offset 7 in cal.json"):
        read_calibration(p)


@pytest.fixture
def dataset_file(tmp_path):
    from openemt_fuzz._fuzzcases import _small_dataset

    p = tmp_path / "data.h5"
    write_dataset(_small_dataset(), p)
    return p


@pytest.mark.parametrize("kind", ["1-D", "2-D", "group"])
def test_couplings_of_the_wrong_shape_are_refused(dataset_file, kind):
    with h5py.File(dataset_file, "a") as f:
        n = f["couplings_real"].shape[0]
        del f["couplings_real"]
        if kind == "group":
            f.create_group("couplings_real")
        else:
            f["couplings_real"] = np.zeros(n if kind == "1-D" else (n, 9))
    with pytest.raises(InputError, match="instead of a 3-D numeric array"):
        read_dataset(dataset_file)
    from openemt.cli import main

    assert main(["solve", dataset_file, "-c", "x.json", "-o", dataset_file.parent / "o.h5"]) == 2


def test_meta_that_is_a_json_list_is_refused(dataset_file):
    with h5py.File(dataset_file, "a") as f:
        f.attrs["meta"] = json.dumps([1, 2])
    with pytest.raises(InputError, match="`meta` is a JSON list"):
        read_dataset(dataset_file)


def test_damaged_dataset_file_is_refused_not_parsed(dataset_file):
    data = bytearray(dataset_file.read_bytes())
    for k in range(200, len(data), 997):  # scatter damage over headers and data
        data[k] ^= 0x5A
    dataset_file.write_bytes(bytes(data))
    with pytest.raises(InputError, match="data.h5"):
        read_dataset(dataset_file)


def test_sealed_files_skip_the_probe_and_edited_files_are_probed(dataset_file, monkeypatch):
    from openemt.io import _h5safe

    assert _h5safe.seal_matches(dataset_file)
    with h5py.File(dataset_file, "a") as f:  # a user edits the file with another tool
        f.attrs["note"] = "edited"
    assert not _h5safe.seal_matches(dataset_file)
    assert read_dataset(dataset_file).n_samples == 12  # probed in a child, then read

    def stuck(path):  # libhdf5 looping on a damaged file
        import time
        time.sleep(60)

    monkeypatch.setattr(_h5safe, "_walk", stuck)
    monkeypatch.setattr(_h5safe, "_checked", set())
    reason = _h5safe.check_readable(dataset_file, timeout=1.0)
    assert reason == "reading its structure did not finish within 1 s"


def test_mat_file_that_crashes_scipy_is_refused(fuzz, tmp_path):
    """A mutation of base_calibration.mat on which scipy's MATLAB reader segfaults (found by
    ``openemt bench fuzz``): read in a child process, refused in one line."""
    from openemt.io import read_ilemt_calibration

    targets, _ = fuzz
    p = tmp_path / "base_calibration.mat"
    p.write_bytes(case_bytes(targets["ilemt_mat"], [("replace_number", 67936859, 391781420)]))
    with pytest.raises(InputError, match="base_calibration.mat that cannot be read"):
        read_ilemt_calibration(p)


def test_mat_file_declaring_a_huge_array_is_refused(fuzz, tmp_path):
    """A mutation of base_calibration.mat whose header asks the MATLAB reader for an impossible
    allocation (MemoryError in the reader; found with more hypothesis examples than the suite
    runs): refused in one line, not raised."""
    from openemt.io import read_ilemt_calibration

    targets, _ = fuzz
    p = tmp_path / "base_calibration.mat"
    p.write_bytes(case_bytes(targets["ilemt_mat"], [("swap_lines", 0, 67693), ("delete", 0, 45)]))
    with pytest.raises(InputError, match=r"cannot be read \(MemoryError"):
        read_ilemt_calibration(p)


def test_mat_reader_dividing_by_a_damaged_size_is_refused(ilemt_dir, monkeypatch):
    """scipy's MATLAB reader raised ZeroDivisionError on a mutation of base_calibration.mat
    (insert(26409, 3263) twice, found with more hypothesis examples than the suite runs; the
    same bytes also crash the reader in other runs, so the exception is replayed here)."""
    from openemt.io import _ilemt_mat
    from openemt.io._isolated import Isolated

    def replay(fn, args, timeout):
        return Isolated("raised", ZeroDivisionError("integer division or modulo by zero"))

    monkeypatch.setattr(_ilemt_mat, "run_isolated", replay)
    with pytest.raises(InputError, match=r"cannot be read \(ZeroDivisionError"):
        _ilemt_mat.read_ilemt_calibration(ilemt_dir / "base_calibration.mat")


@pytest.mark.parametrize("jops", [
    [("set", 876459399, 576002250), ("delete", 702019669, 190583558)],
    [("set", 655812843, 507664122), ("delete", 176772873, 340678404)],
    [("delete", 312776518, 23556280), ("set", 735772479, 672393533),
     ("set", 220097158, 953567227)],
    [("set", 678289926, 954243000), ("delete", 2587732, 432249899)],
    [("set", 962363403, 559980367)],
    [("set", 544212379, 634274665)],
])
def test_malformed_correction_values_are_refused(fuzz, tmp_path, jops):
    from openemt.correct import read_correction

    targets, _ = fuzz
    p = tmp_path / "corr.json"
    p.write_bytes(case_bytes(targets["correction_json"], [], jops))
    with pytest.raises(InputError, match="correction file corr.json: expected"):
        read_correction(p)


@pytest.mark.parametrize("ops", [[("replace_number", 0, 19)]])
def test_sign_cell_spanning_lines_is_refused_in_one_line(fuzz, tmp_path, ops):
    """A mutated number that turns ``[-1 -1 1]`` into a bracket spanning two lines: the message
    quotes the bracket on one line (found with more hypothesis examples than the suite runs)."""
    from openemt.io._ilemt import parse_sign_options

    targets, _ = fuzz
    p = tmp_path / "local_cal_options.m"
    p.write_bytes(case_bytes(targets["ilemt_options"], ops))
    with pytest.raises(InputError, match="expected numeric signs") as info:
        parse_sign_options(p)
    assert "\n" not in str(info.value)
