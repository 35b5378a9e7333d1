"""The compile notice: said when a kernel's numba cache is cold (missing or stale), not when it
is warm, never with --quiet; the real kernels read as cold with an empty NUMBA_CACHE_DIR; every
announced kernel has a warm-up call that compiles the types the commands pass."""

import argparse
import importlib
import io
import os
import subprocess
import sys

import pytest

from openemt._compile_notice import (
    COLD_START_KERNELS,
    LIVE_KERNELS,
    PLANAR_KERNELS,
    SOLVER_KERNELS,
    announce_compile,
    cold_kernels,
)

_KERNEL = """from numba import njit


@njit(cache=True)
def add_one(x):
    return x + 1
"""


@pytest.fixture
def kernel_module(tmp_path, monkeypatch):
    """A fresh module with one cached kernel; its cache goes to a folder of its own."""
    name = f"openemt_notice_probe_{os.getpid()}_{tmp_path.name}".replace("-", "_")
    (tmp_path / f"{name}.py").write_text(_KERNEL)
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module(name)
    yield mod, tmp_path / f"{name}.py", f"{name}:add_one"
    sys.modules.pop(name, None)


def test_cold_then_warm_then_stale(kernel_module):
    mod, path, spec = kernel_module
    assert cold_kernels([spec]) == [spec]                 # nothing cached yet
    out = io.StringIO()
    assert announce_compile(out, "probe kernels", kernels=[spec]) is True
    assert out.getvalue() == "compiling 1 probe kernel (first run only) ...\n"

    assert mod.add_one(1) == 2                             # compiles and writes the cache
    assert cold_kernels([spec]) == []
    out = io.StringIO()
    assert announce_compile(out, "probe kernels", kernels=[spec]) is False
    assert out.getvalue() == ""

    # an edited source makes the cache stale: numba would compile again, so it is cold
    path.write_text(_KERNEL + "\n# edited\n")
    os.utime(path, (path.stat().st_atime, path.stat().st_mtime + 5))
    importlib.reload(mod)
    assert cold_kernels([spec]) == [spec]


def test_quiet_and_namespace(kernel_module, capsys):
    _, _, spec = kernel_module
    assert announce_compile(argparse.Namespace(quiet=True), kernels=[spec]) is False
    assert announce_compile(argparse.Namespace(quiet=False), "probe kernels",
                            kernels=[spec], seconds=12) is True
    assert capsys.readouterr().err == "compiling 1 probe kernel (first run only, about 12 s) ...\n"
    said = []
    assert announce_compile(said.append, "probe kernels", kernels=[spec, spec]) is True
    assert said == ["compiling 2 probe kernels (first run only) ..."]


def test_uninspectable_function_counts_as_cold(tmp_path, monkeypatch):
    # not a caching dispatcher: the state is unknown, so the notice is said rather than hidden
    (tmp_path / "openemt_notice_plain.py").write_text("def f():\n    return 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert cold_kernels(["openemt_notice_plain:f"]) == ["openemt_notice_plain:f"]
    sys.modules.pop("openemt_notice_plain", None)


def test_real_kernels_are_cold_with_an_empty_cache(tmp_path):
    probe = ("from openemt._compile_notice import *; "
             "print(len(cold_kernels(SOLVER_KERNELS + COLD_START_KERNELS + PLANAR_KERNELS "
             "+ LIVE_KERNELS)))")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    assert int(out.stdout) == len(SOLVER_KERNELS + COLD_START_KERNELS + PLANAR_KERNELS
                                  + LIVE_KERNELS)
    # looking compiled nothing: no cache index or data file was written
    assert [p.name for p in tmp_path.rglob("*.nb[ic]")] == []


def _dispatcher(spec):
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


def test_every_announced_kernel_is_compiled_by_its_warm_up():
    from openemt._compile_notice import _WARM_UP

    specs = SOLVER_KERNELS + COLD_START_KERNELS + LIVE_KERNELS + PLANAR_KERNELS
    for spec in specs:               # a kernel's module registers its warm-up when imported
        _dispatcher(spec)            # (as cold_kernels imports it); the packages load lazily
    assert set(specs) <= set(_WARM_UP)
    for spec in specs:
        _WARM_UP[spec]()                         # compiles, or loads from the cache
        assert len(_dispatcher(spec).signatures) >= 1, spec
    assert cold_kernels(specs) == []


def test_after_the_warm_up_track_compiles_nothing_more(capsys):
    """The warm-up compiles the very types ``track`` passes: the run adds no specialisation
    (one would compile inside the tracking step, after the notice)."""
    from openemt._compile_notice import _WARM_UP
    from openemt.cli import main

    specs = SOLVER_KERNELS + COLD_START_KERNELS + LIVE_KERNELS
    for spec in specs:
        _dispatcher(spec)            # imports the kernel's module, which registers its warm-up
        _WARM_UP[spec]()
    before = {spec: len(_dispatcher(spec).signatures) for spec in specs}
    assert main(["track", "--source", "sim", "--no-igtl", "--duration", "0.05", "--fast",
                 "--json"]) == 0
    capsys.readouterr()
    assert {spec: len(_dispatcher(spec).signatures) for spec in specs} == before
