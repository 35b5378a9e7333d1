"""Hostile inputs (docs/robustness.md#hostile-inputs): every reader reads only what its file
holds, never blocks on a FIFO or a device, refuses declared-shape bombs before allocating and
bounds the work a tracker, board or calibration file sets; each refusal is one line, and the
CLI exits 2 with one ``error:`` line and no output. The long run is ``openemt bench fuzz``."""

import contextlib
import os
import signal

import h5py
import numpy as np
import pytest
from openemt_fuzz import _fuzzhostile_readers as H

from openemt._errors import InputError
from openemt.io import read_board, read_calibration, read_dataset, write_dataset
from openemt.io._h5safe import H5_FLOOR_BYTES, check_structure, open_h5
from openemt.io._safefile import check_text_nesting, read_limited
from openemt.live import read_tracker
from openemt.signal import read_raw
from openemt.solve import read_poses


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    return H.build_seeds(tmp_path_factory.mktemp("hostile-seeds"))


def _case(name, cli=None):
    for c in H.cases():
        if c.name == name and (cli is None or (c.cli and c.cli[0] == cli)):
            return c
    raise KeyError(name)


def _build(name, tmp_path, seeds):
    folder = tmp_path / "in"
    folder.mkdir()
    return _case(name).build(folder, seeds)


def _one_line(exc_info):
    msg = str(exc_info.value)
    assert "\n" not in msg and msg
    return msg


# ------------------------------------------------------------ HDF5: links, storage, filters

HDF5_CASES = [
    ("external_link_etc", r"got 'couplings_real' as an external link to '/etc/passwd'"),
    ("external_link_fifo", r"got 'couplings_real' as an external link to '.*fifo'"),
    ("external_storage_etc", r"got 'couplings_real' stored in external file '/etc/passwd'"),
    ("external_storage_environ", r"stored in external file '/proc/self/environ'"),
    ("external_storage_fifo", r"stored in external file '.*fifo'"),
    ("virtual_dataset", r"'couplings_real' as a virtual dataset"),
    ("soft_link_dangling", r"'stage' as a soft link to '/no/such/object', which names no"),
    ("soft_link_climbing", r"'stage' as a soft link to '../../x'"),
    ("plugin_filter", r"built-in filters .* with filter 32000 \('lzf'\)"),
    ("declared_rows_1e8", r"declare at most 64 MiB .* got 6.71 GiB"),
    ("stage_rows_differ", (r"data.h5: expected `stage` to have shape \(12, 6\) like "
                           r"`couplings_real`, got shape \(17, 6\)")),
    ("pattern_rows_differ", r"expected `pattern` to have shape \(12,\) .* got shape \(17,\)"),
]


@pytest.mark.parametrize("kind,match", HDF5_CASES)
def test_dataset_reader_refuses_hostile_structure(kind, match, tmp_path, seeds):
    path = _build(f"dataset:{kind}", tmp_path, seeds)
    with pytest.raises(InputError, match=match) as exc:
        read_dataset(path)
    _one_line(exc)


def test_unsealed_hostile_file_refused_by_the_probe_with_its_own_message(tmp_path, seeds):
    path = _build("dataset:external_link_etc_unsealed", tmp_path, seeds)
    with pytest.raises(InputError, match="as an external link to '/etc/passwd'") as exc:
        read_dataset(path)
    assert "damaged" not in _one_line(exc)


@pytest.mark.parametrize("reader,read,name", [("raw", read_raw, "samples"),
                                              ("poses", read_poses, "poses")])
@pytest.mark.parametrize("kind", ["external_link_etc", "external_storage_environ",
                                  "virtual_dataset", "declared_rows_1e8"])
def test_raw_and_poses_readers_refuse_hostile_structure(reader, read, name, kind, tmp_path,
                                                         seeds):
    path = _build(f"{reader}:{kind}", tmp_path, seeds)
    with pytest.raises(InputError) as exc:
        read(path)
    msg = _one_line(exc)
    assert "data.h5" in msg and (repr(name) in msg or "declare at most" in msg)


def test_poses_rows_checked(tmp_path, seeds):
    path = _build("poses:status_rows_differ", tmp_path, seeds)
    with pytest.raises(InputError, match=r"`status` to have shape \(12,\) like `poses`"):
        read_poses(path)


def test_files_within_the_rules_still_read(tmp_path, seeds):
    """What the checks must not refuse: deflate/shuffle/Fletcher-32 data, soft links to
    objects of the file, and a file declaring close to the floor of the budget."""
    ds = read_dataset(seeds / "seed.h5")
    path = tmp_path / "ok.h5"
    write_dataset(ds, path)
    with h5py.File(path, "r+") as f:
        data = f["stage"][()]
        del f["stage"]
        f.create_dataset("stage", data=data, compression="gzip", shuffle=True,
                         fletcher32=True, chunks=True)
        f["stage_alias"] = h5py.SoftLink("/stage")
        f["extra"]["lr_alias"] = h5py.SoftLink(min(f["extra"]))   # relative
        n = (H5_FLOOR_BYTES // 2) // 8
        f.create_dataset("unused", shape=(n,), dtype="f8", chunks=(65536,))
    back = read_dataset(path)
    assert np.array_equal(back.stage, ds.stage)
    with h5py.File(path, "r") as f:
        check_structure(f, "ok.h5")
    # the same file declaring past the floor is refused: the budget check can fail
    with h5py.File(path, "r+") as f:
        del f["unused"]
        f.create_dataset("unused", shape=(2 * H5_FLOOR_BYTES // 8,), dtype="f8",
                         chunks=(65536,))
    with pytest.raises(InputError, match="'unused'"):
        read_dataset(path)


# ------------------------------------------------------------ FIFO and device paths


@pytest.mark.parametrize("reader,filename", [("dataset", "data.h5"), ("raw", "raw.h5"),
                                             ("calibration", "cal.json"),
                                             ("tracker", "tracker.toml"),
                                             ("board", "board.toml"), ("csv", "data.csv"),
                                             ("ndi", "export.tsv")])
@pytest.mark.parametrize("kind,what", [("fifo", "FIFO"), ("device", "character device")])
def test_fifo_and_device_paths_refused_without_blocking(reader, filename, kind, what,
                                                        tmp_path, seeds):
    path = _build(f"{reader}:{kind}:{filename}", tmp_path, seeds)
    read = H._readers()[reader]
    with _no_blocking(), pytest.raises(InputError,
                                       match=f"regular file.* which is a {what}") as exc:
        read(path)
    _one_line(exc)


@contextlib.contextmanager
def _no_blocking(seconds=10):
    """Fail (instead of hanging the test run) if the body blocks longer than ``seconds``."""
    def hang(*_):
        raise TimeoutError("the reader blocked")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("name", ["local_cal_options.m", "soYoutZup_seYoutZup_md.dat"])
def test_fifo_in_an_ilemt_folder_is_refused_not_skipped(name, tmp_path):
    from openemt.datasets import path as dataset_path
    from openemt.io import import_ilemt_folder

    src = dataset_path("cal_9_15_premo_cmu") / "soYoutZup_seYoutZup_mdtrans.dat"
    (tmp_path / src.name).write_bytes(src.read_bytes())
    os.mkfifo(tmp_path / name)
    with _no_blocking(), pytest.raises(InputError, match=f"{name}' which is a FIFO"):
        import_ilemt_folder(tmp_path)


def test_read_limited_checks_the_opened_file_and_its_size(tmp_path):
    p = tmp_path / "a.json"
    p.write_bytes(b"x" * 100)
    assert read_limited(p, "a file", 100) == b"x" * 100
    with pytest.raises(InputError, match="at most 99 bytes, got a.json of 100 bytes"):
        read_limited(p, "a file", 99)
    with pytest.raises(FileNotFoundError, match="missing file"):
        read_limited(tmp_path / "nope", "a file", 99)
    with pytest.raises(InputError, match="which is a folder"):
        read_limited(tmp_path, "a file", 99)


# ------------------------------------------------------------ tracker, board, calibration


def test_toml_nesting_check_ignores_strings_and_comments():
    deep = "[" * 40 + "]" * 40
    check_text_nesting(f'a = "{deep}"\nb = \'\'\'\n{deep}\n\'\'\' # {deep}\nc = [[1]]\n',
                       "x", "f.toml")
    with pytest.raises(InputError, match="nested at most 32 levels deep, got deeper nesting "
                                         "at line 2"):
        check_text_nesting(f"a = 1\nb = {deep}\n", "x", "f.toml")


TRACKER_CASES = [
    ("deep_nesting", r"nested at most 32 levels deep"),
    ("sample_rate_1e15", r"`adc.sample_rate` to be at most 1e\+07 Hz, got 1000000000000000.0"),
    ("channels_1e18", r"`adc.channels` to be at most 256, got 1000000000000000000"),
    ("output_rate_tiny", r"`demodulation.output_rate` .* at most 33554432 values"),
    ("sensors_20000", r"`sensors` to be a list of at most 256 tables, got 20001 items"),
    ("list_20M", r"tracker description file \(TOML\) of at most 1 MiB, got tracker.toml of"),
    ("carriers_300", r"`source.frequencies` to be a list of at most 256 numbers, got 300"),
    ("seed_negative", r"`simulation.seed` to be an integer in 0..2\*\*63-1, got -1"),
]


@pytest.mark.parametrize("kind,match", TRACKER_CASES)
def test_hostile_tracker_files_refused_naming_file_and_key(kind, match, tmp_path, seeds):
    path = _build(f"tracker:{kind}", tmp_path, seeds)
    with pytest.raises(InputError, match=match) as exc:
        read_tracker(path)
    assert "tracker.toml" in _one_line(exc)


def test_tracker_sensor_count_limit(tmp_path, seeds):
    from openemt.live._tracker_file import MAX_SENSORS

    text = (seeds / "simulated.toml").read_text().replace("channels = 6 ", "channels = 200 ")
    text += "".join(f'\n[[sensors]]\nname = "s{i}"\nchannels = [{6 + i}]\n'
                    for i in range(MAX_SENSORS))
    (tmp_path / "t.toml").write_text(text)
    with pytest.raises(InputError, match=f"`sensors` to be at most {MAX_SENSORS} sensors, "
                                         f"got {MAX_SENSORS + 1} sensors"):
        read_tracker(tmp_path / "t.toml")


@pytest.mark.parametrize("kind,match", [
    ("deep_nesting", r"nested at most 64 levels deep"),
    ("sensor_coils_20000", r"`model.L_se` with at most 64 columns \(coils\), got 20000"),
    ("list_20M", r"at most 2000000 values, got up to 20000\d{3} in cal.json"),
])
def test_hostile_calibration_files(kind, match, tmp_path, seeds):
    path = _build(f"calibration:{kind}", tmp_path, seeds)
    with pytest.raises(InputError, match=match) as exc:
        read_calibration(path)
    assert "cal.json" in _one_line(exc)


@pytest.mark.parametrize("kind,match", [
    ("deep_nesting", r"board.toml: expected a TOML board file nested at most 32"),
    ("segments_56_coils_10000_turns", r"at most 2000000 straight segments"),
])
def test_hostile_board_files(kind, match, tmp_path, seeds):
    path = _build(f"board:{kind}", tmp_path, seeds)
    with pytest.raises(InputError, match=match) as exc:
        read_board(path)
    _one_line(exc)


def test_board_coil_count_limit(tmp_path, seeds):
    from openemt.board._geometry import MAX_BOARD_COILS

    text = "".join(f'\n[[coils]]\nname = "c{i}"\ncenter = [0.0, 0.0, 0.0]\n'
                   f'turns_per_layer = 1\nouter_size = 0.01\n' for i in range(MAX_BOARD_COILS + 1))
    (tmp_path / "b.toml").write_text(text)
    with pytest.raises(InputError, match=f"at most {MAX_BOARD_COILS} entries in 'coils', got "
                                         f"{MAX_BOARD_COILS + 1}"):
        read_board(tmp_path / "b.toml")


# ------------------------------------------------------------ through the CLI (child process)


@pytest.mark.parametrize("name,cli", [
    ("dataset:external_storage_etc", "info"),
    ("dataset:external_storage_etc", "solve"),
    ("dataset:external_link_fifo", "solve"),
    ("dataset:declared_rows_1e8", "info"),
    ("dataset:declared_rows_1e8", "solve"),
    ("dataset:fifo:data.h5", "info"),
    ("tracker:deep_nesting", "track"),
    ("calibration:deep_nesting", "info"),
])
def test_cli_exits_2_with_one_error_line_and_no_output(name, cli, tmp_path, seeds):
    """Run in a child process with a time limit: exit 2, one ``error:`` line, nothing left in
    the output folder, and (for the 10**8-row file) a peak far below what the rows declare."""
    out = H.run_case(_case(name, cli), tmp_path / "case", seeds, cli=True, time_limit=60)
    assert out.kind == "held", out
    assert out.peak_bytes < H.MEMORY_LIMIT_BYTES


def test_classifier_flags_every_bad_outcome():
    ok = H._classify(2, "error: expected x, got y\n", 1.0, 1 << 20, [])
    assert ok.kind == "held"
    assert H._classify(0, "", 1.0, 1 << 20, []).kind == "accepted"
    assert H._classify(None, "", 31.0, 1 << 20, []).kind == "hang"
    assert H._classify(2, "error: a\nerror: b\n", 1.0, 1 << 20, []).kind == "crash"
    assert H._classify(1, "Traceback\nKeyError\n", 1.0, 1 << 20, []).kind == "crash"
    assert H._classify(2, "error: a\n", 1.0, 1 << 20, ["poses.h5"]).kind == "garbage"
    assert H._classify(2, "error: a\n", 1.0, H.MEMORY_LIMIT_BYTES + 1, []).kind == "memory"
    assert H._classify(3, "error: missing file\n", 1.0, 1 << 20, []).kind == "vague"


def test_open_h5_is_the_one_door(tmp_path, seeds):
    """Every HDF5 reader of openemt opens files through open_h5 (no other h5py.File read)."""
    import pathlib
    import re

    import openemt

    src = pathlib.Path(openemt.__file__).parent
    readers = []
    for p in src.rglob("*.py"):
        for m in re.finditer(r"(?<!``)h5py\.File\(([^)]*)\)", p.read_text()):
            args = m.group(1)
            if '"w"' in args or '"r+"' in args or "tmp" in args or p.name == "_h5safe.py":
                continue
            readers.append(f"{p.relative_to(src)}: {m.group(0)}")
    assert readers == [], readers
    with open_h5(seeds / "seed.h5", "a dataset") as f:
        assert "couplings_real" in f
    assert os.path.exists(seeds / "seed.h5")


def test_link_and_attribute_counts_bounded(monkeypatch, tmp_path):
    import openemt.io._h5safe as h5safe

    with h5py.File(tmp_path / "many.h5", "w") as f:
        for i in range(8):
            f[f"a{i}"] = np.zeros(3)
        for i in range(20):
            f.attrs[f"k{i}"] = i
    monkeypatch.setattr(h5safe, "MAX_H5_LINKS", 30)
    with h5py.File(tmp_path / "many.h5", "r") as f:
        check_structure(f, "many.h5")
        monkeypatch.setattr(h5safe, "MAX_H5_LINKS", 7)
        with pytest.raises(InputError, match="at most 7 objects, got many.h5 with more"):
            check_structure(f, "many.h5")
        monkeypatch.setattr(h5safe, "MAX_H5_LINKS", 10)
        with pytest.raises(InputError, match="at most 10 attributes, got many.h5 with more"):
            check_structure(f, "many.h5")
