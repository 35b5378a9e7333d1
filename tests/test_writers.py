"""Writers never break what they replace (docs/robustness.md#writers): outputs onto devices,
FIFOs, sockets, folders and symbolic links; long names; fsync; a full disk; stale temporaries
of killed runs; the bundled-dataset folder."""

from __future__ import annotations

import errno
import os
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from openemt import _atomic
from openemt._atomic import remove_stale_temporaries
from openemt._errors import InputError
from openemt.cli import main
from openemt.io import Dataset, atomic_h5, atomic_path, read_dataset, write_dataset
from openemt.io._h5write import GuardedFile, raise_if_write_failed


def _dataset(n: int = 50) -> Dataset:
    rng = np.random.default_rng(0)
    return Dataset(couplings=rng.normal(size=(n, 3, 3)), stage=np.zeros((n, 6)),
                   source_fixture=np.array(["a"] * n), sensor_fixture=np.array(["b"] * n),
                   pattern=np.array(["md"] * n), file_index=np.zeros(n, dtype=np.int64),
                   files=("f",))


def _refused(capsys, argv, *words) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and err.strip().count("\n") == 0, err
    for w in words:
        assert w in err, err
    return err


def _import_argv(ilemt_dir, out) -> list[str]:
    return ["import", "ilemt", str(ilemt_dir), "-o", str(out), "--quiet"]


# --------------------------------------------------------------------------- refused targets

def test_fifo_output_is_refused_before_any_work(ilemt_dir, tmp_path, capsys, monkeypatch):
    fifo = tmp_path / "out.h5"
    os.mkfifo(fifo)
    import openemt.cli._import_ as cmd

    monkeypatch.setattr(cmd, "run", lambda args: pytest.fail("the command ran"))
    _refused(capsys, _import_argv(ilemt_dir, fifo), "FIFO", str(fifo))
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    with pytest.raises(InputError, match="FIFO"):  # the library refuses it too
        write_dataset(_dataset(), fifo)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_character_device_output_is_refused(ilemt_dir, tmp_path, capsys):
    dev = tmp_path / "null"
    st = os.stat("/dev/null")
    try:
        os.mknod(dev, stat.S_IFCHR | 0o666, st.st_rdev)
    except (PermissionError, OSError) as exc:
        pytest.skip(f"cannot create a device node here: {exc}")
    _refused(capsys, _import_argv(ilemt_dir, dev), "character device")
    assert stat.S_ISCHR(os.lstat(dev).st_mode)
    link = tmp_path / "link.h5"  # a link to the device is refused like the device
    link.symlink_to(dev)
    _refused(capsys, _import_argv(ilemt_dir, link), "character device")
    assert stat.S_ISCHR(os.lstat(dev).st_mode) and link.is_symlink()


def test_socket_and_folder_outputs_are_refused(tmp_path, capsys, ilemt_dir):
    folder = tmp_path / "out.h5"
    folder.mkdir()
    _refused(capsys, _import_argv(ilemt_dir, folder), "a folder")
    sock_path = tmp_path / "s.h5"
    if len(str(sock_path)) >= 100:
        pytest.skip("temporary path too long for a Unix socket")
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(sock_path))
        _refused(capsys, _import_argv(ilemt_dir, sock_path), "socket")
        assert stat.S_ISSOCK(os.lstat(sock_path).st_mode)


def test_output_folder_of_demo_must_be_a_folder(tmp_path, capsys):
    plain = tmp_path / "file"
    plain.write_text("keep")
    _refused(capsys, ["demo", "-o", str(plain), "--quiet"], "expected a folder")
    assert plain.read_text() == "keep"


def test_missing_output_folder_is_refused_before_any_work(ilemt_dir, tmp_path, capsys,
                                                         monkeypatch):
    import openemt.cli._import_ as cmd

    monkeypatch.setattr(cmd, "run", lambda args: pytest.fail("the command ran"))
    _refused(capsys, _import_argv(ilemt_dir, tmp_path / "missing" / "out.h5"),
             "expected an existing folder for output", "missing folder")


def test_symlink_loop_output_is_one_error(tmp_path, capsys, ilemt_dir):
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    a.symlink_to(b)
    b.symlink_to(a)
    _refused(capsys, _import_argv(ilemt_dir, a), "symbolic link loop")
    with pytest.raises(InputError, match="symbolic link loop"):
        write_dataset(_dataset(), a)
    assert a.is_symlink() and b.is_symlink()


def test_outputs_into_the_bundled_dataset_folder_are_refused(ilemt_dir, capsys, tmp_path):
    inside = ilemt_dir.parent / "new.h5"
    _refused(capsys, ["simulate", "--preset", "dipole-approx", "-o", str(inside), "--quiet"],
             "bundled-dataset folder")
    with pytest.raises(InputError, match="bundled-dataset folder"):
        write_dataset(_dataset(), inside)
    link = tmp_path / "link.h5"  # through a symbolic link as well
    link.symlink_to(inside)
    with pytest.raises(InputError, match="bundled-dataset folder"):
        write_dataset(_dataset(), link)
    assert not inside.exists()


# --------------------------------------------------------------------------- what is written

def test_symlinked_output_is_written_through_keeping_the_link(tmp_path):
    real_dir = tmp_path / "real"
    real_dir.mkdir()
    target = real_dir / "data.h5"
    target.write_text("old")
    link = tmp_path / "link.h5"
    link.symlink_to(target)
    write_dataset(_dataset(), link)
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert read_dataset(target).n_samples == 50
    dangling = tmp_path / "dangling.h5"  # a link to a missing file creates that file
    dangling.symlink_to(real_dir / "new.h5")
    write_dataset(_dataset(), dangling)
    assert dangling.is_symlink() and (real_dir / "new.h5").is_file()
    # the temporaries went beside the target, and none is left anywhere
    assert sorted(p.name for p in real_dir.iterdir()) == ["data.h5", "new.h5"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling.h5", "link.h5", "real"]


def test_names_up_to_name_max_work(tmp_path):
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    name = "n" * (limit - 3) + ".h5"
    assert len(name.encode()) == limit
    write_dataset(_dataset(), tmp_path / name)
    assert read_dataset(tmp_path / name).n_samples == 50
    with atomic_path(tmp_path / ("t" * limit)) as tmp:
        tmp.write_text("x")
    assert (tmp_path / ("t" * limit)).read_text() == "x"
    with pytest.raises(InputError, match="within the file system's limit") as exc:
        write_dataset(_dataset(), tmp_path / ("m" * (limit + 1)))  # one error naming it
    assert "m" * 20 in str(exc.value) and "\n" not in str(exc.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, "t" * limit])


def test_data_is_fsynced_before_the_rename_and_the_folder_after(tmp_path, monkeypatch):
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", stat.S_ISDIR(os.fstat(fd).st_mode), os.fstat(fd).st_size))
        real_fsync(fd)

    def replace(a, b):
        events.append(("replace",))
        real_replace(a, b)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    write_dataset(_dataset(), tmp_path / "d.h5")
    size = (tmp_path / "d.h5").stat().st_size
    assert events == [("fsync", False, size), ("replace",), ("fsync", True, events[2][2])]


def test_replaced_file_keeps_its_permissions(tmp_path):
    out = tmp_path / "cal.json"
    out.write_text("old")
    out.chmod(0o600)
    with atomic_path(out) as tmp:
        tmp.write_text("new")
    assert out.read_text() == "new" and stat.S_IMODE(out.stat().st_mode) == 0o600


# --------------------------------------------------------------------------- full disk, EIO

def _failing_pwrite(code: int, after: int = 0):
    calls = {"n": 0}
    real = os.pwrite

    def pwrite(fd, data, offset):
        calls["n"] += 1
        if calls["n"] > after:
            raise OSError(code, os.strerror(code))
        return real(fd, data, offset)

    return pwrite


@pytest.mark.parametrize(("code", "words"), [(errno.ENOSPC, "disk full writing"),
                                             (errno.EIO, "input/output error writing"),
                                             (errno.EDQUOT, "disk quota exceeded writing")])
def test_hdf5_write_errors_are_one_error_and_leave_nothing(tmp_path, monkeypatch, code, words):
    out = tmp_path / "d.h5"
    monkeypatch.setattr(os, "pwrite", _failing_pwrite(code, after=2))
    with pytest.raises(OSError) as exc:
        write_dataset(_dataset(2000), out)
    assert str(exc.value).startswith(f"{words} {str(out)!r}") and exc.value.errno == code
    assert list(tmp_path.iterdir()) == []


def test_text_write_errors_are_one_error_and_leave_nothing(tmp_path):
    out = tmp_path / "r.csv"
    out.write_text("previous")
    with pytest.raises(OSError, match=r"^disk full writing .*r\.csv"), atomic_path(out) as tmp:
        tmp.write_text("partial")
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert out.read_text() == "previous" and [p.name for p in tmp_path.iterdir()] == ["r.csv"]


def test_cli_full_disk_is_exit_2_with_one_line(ilemt_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(os, "pwrite", _failing_pwrite(errno.ENOSPC, after=1))
    out = tmp_path / "imp.h5"
    _refused(capsys, _import_argv(ilemt_dir, out), f"disk full writing {str(out)!r}")
    assert list(tmp_path.iterdir()) == []


def test_guarded_file_keeps_what_could_not_be_written(tmp_path, monkeypatch):
    fd = os.open(tmp_path / "g", os.O_RDWR | os.O_CREAT)
    try:
        g = GuardedFile(fd, "g")
        g.write(b"abcdef")
        monkeypatch.setattr(os, "pwrite", _failing_pwrite(errno.ENOSPC))
        g.seek(4)
        g.write(b"XYZ")  # fails on the disk: kept for the library's later reads
        g.seek(0)
        assert g.read(9) == b"abcdXYZ" and g.read() == b""
        g.seek(0, os.SEEK_END)
        assert g.tell() == 7
        with pytest.raises(OSError) as exc:
            g.check()
        assert exc.value.errno == errno.ENOSPC
    finally:
        os.close(fd)


def test_streaming_writer_stops_at_the_first_failed_block(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "pwrite", _failing_pwrite(errno.ENOSPC))
    with pytest.raises(OSError, match="disk full"), atomic_h5(tmp_path / "p.h5") as f:
        d = f.create_dataset("x", shape=(10**6,), dtype="f8", chunks=(1000,))
        d[:1000] = 1.0
        f.flush()
        with pytest.raises(OSError):
            raise_if_write_failed(f)
        raise_if_write_failed(f)
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def small_tmpfs(tmp_path):
    """A 2 MB tmpfs (needs root and a kernel that lets this process mount)."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)], check=False,
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False, capture_output=True)


def test_full_tmpfs_hdf5_writer_exits_2_without_a_crash(small_tmpfs, ilemt_dir):
    # before: exit 139 (segmentation fault inside libhdf5 at file close), temporary file left
    (small_tmpfs / "filler").write_bytes(b"\0" * 1_700_000)
    out = small_tmpfs / "imp.h5"
    r = subprocess.run([sys.executable, "-c",
                        "import sys; from openemt.cli import main; sys.exit(main(sys.argv[1:]))",
                        *_import_argv(ilemt_dir, out)], check=False, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2, r.stderr[-2000:]
    assert r.stderr.strip() == f"error: disk full writing {str(out)!r} (no space left on device; " \
                               "nothing was written)"
    assert sorted(p.name for p in small_tmpfs.iterdir()) == ["filler"]


# --------------------------------------------------------------------------- stale temporaries

def test_killed_run_temporary_is_removed_by_the_next_run_writing_another_name(tmp_path):
    code = ("import sys, time\n"
            "from openemt.io import atomic_path\n"
            f"with atomic_path({str(tmp_path / 'big.h5')!r}, suffix='.h5') as tmp:\n"
            "    tmp.write_bytes(b'x' * 100000)\n"
            "    print(tmp.name, flush=True)\n"
            "    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        name = proc.stdout.readline().strip()
        assert name.startswith(".openemt-") and (tmp_path / name).exists()
        # while its process lives, another run leaves it alone
        assert remove_stale_temporaries(tmp_path / "other.json") == []
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=20)
    assert (tmp_path / name).exists()  # SIGKILL: nothing could clean up
    with atomic_path(tmp_path / "other.json") as tmp:
        tmp.write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.json"]


def test_only_openemt_temporaries_of_this_machine_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    host = _atomic._HOST
    other_host = f"{(int(host, 16) + 1) % 2**32:08x}"
    names = {f".openemt-{host}-{dead}-abc_1234.h5": True,
             f".openemt-{host}-{os.getpid()}-abc_1234.h5": False,   # a live process
             f".openemt-{other_host}-{dead}-abc_1234.h5": False,  # another machine
             f".openemt-{host}-{dead}-notes.txt.bak": False,       # not a temporary name
             ".hidden": False, "plain.h5": False}
    for n in names:
        (tmp_path / n).write_text("x")
    removed = {p.name for p in remove_stale_temporaries(tmp_path / "x")}
    assert removed == {n for n, gone in names.items() if gone}
    assert {p.name for p in tmp_path.iterdir()} == {n for n, gone in names.items() if not gone}


def test_temporary_names_are_short_and_recognised():
    tmp_name = f".openemt-{_atomic._HOST}-{4194304}-k2j4h5a8.h5"
    assert len(tmp_name) < 40
    assert _atomic._stale_owner(tmp_name) == 4194304
    assert _atomic._stale_owner(Path("x.h5").name) is None


# --------------------------------------------------------------------------- the bench section

def test_bench_hostile_writers_section_holds():
    """A bounded run of ``openemt bench fuzz``'s hostile_writers section: one fast writer, every
    kind but ``killed`` (a fresh interpreter per case; pinned above by
    test_killed_run_temporary_is_removed_by_the_next_run_writing_another_name); the long run
    covers every writer and kind."""
    from openemt_fuzz._fuzzhostile_writers import KINDS, hostile_writers

    kinds = [k for k in KINDS if k != "killed"]
    out = hostile_writers(1, writers=["track_save_raw"], kinds=kinds, time_limit=60)
    assert out["broken"] == 0, out["examples"]
    assert out["cases"] == len(kinds) == out["held"] + out["skipped"]
    assert set(out["by_kind"]) == set(kinds)
