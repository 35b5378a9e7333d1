"""The compile notice: said when a kernel's numba cache is cold (missing or stale), not when it
is warm, never with --quiet; the real kernels read as cold with an empty NUMBA_CACHE_DIR; every
announced kernel has a warm-up call that compiles the types the commands pass."""

import argparse
import importlib
import io
import os
import subprocess
import sys
import types

import numpy as np
import pytest

from openemt._compile_notice import (
    BOARD_LM_KERNELS,
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


def test_watch_says_an_unannounced_compile_once(kernel_module):
    """A compile that no notice announced (a set-up step's, on the side) is said once within
    the watch; a compile under announce_compile is not said again; with --quiet nothing."""
    from openemt._compile_notice import watch_compiles

    mod, _, spec = kernel_module
    out = io.StringIO()
    with watch_compiles(out, "probe kernels") as seen:
        assert mod.add_one(1) == 2                          # compiles: said
        assert mod.add_one(2.5) == 3.5                      # another specialisation: not again
    assert out.getvalue() == "compiling probe kernels (first run only) ...\n"
    assert seen == [spec, spec]
    with watch_compiles(out) as seen:                       # cached now: nothing compiles
        mod.add_one(1)
    assert seen == [] and out.getvalue().count("\n") == 1
    quiet = argparse.Namespace(quiet=True)
    with watch_compiles(quiet) as seen:
        mod.add_one(np.int32(3))                            # compiles, said to no one
    assert len(seen) == 1


def test_watch_leaves_announced_compiles_to_their_notice(kernel_module, monkeypatch):
    from openemt import _compile_notice as notice

    mod, _, spec = kernel_module
    monkeypatch.setitem(notice._WARM_UP, spec, lambda: mod.add_one(1))
    out, said = io.StringIO(), io.StringIO()
    with notice.watch_compiles(said) as seen:
        assert notice.announce_compile(out, "probe kernels", kernels=[spec]) is True
    assert out.getvalue() == "compiling 1 probe kernel (first run only) ...\n"
    assert said.getvalue() == "" and seen == []


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
             "+ LIVE_KERNELS + BOARD_LM_KERNELS)))")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                         timeout=120, check=True)
    assert int(out.stdout) == len(SOLVER_KERNELS + COLD_START_KERNELS + PLANAR_KERNELS
                                  + LIVE_KERNELS + BOARD_LM_KERNELS)
    # looking compiled nothing: no cache index or data file was written
    assert [p.name for p in tmp_path.rglob("*.nb[ic]")] == []


def _dispatcher(spec):
    module, _, name = spec.partition("@")[0].partition(":")
    return getattr(importlib.import_module(module), name)


def test_every_announced_kernel_is_compiled_by_its_warm_up():
    from openemt._compile_notice import _WARM_UP

    specs = SOLVER_KERNELS + COLD_START_KERNELS + LIVE_KERNELS + PLANAR_KERNELS \
        + BOARD_LM_KERNELS
    for spec in specs:               # a kernel's module registers its warm-up when imported
        _dispatcher(spec)            # (as cold_kernels imports it); the packages load lazily
    assert set(specs) <= set(_WARM_UP)
    for spec in specs:
        _WARM_UP[spec]()                         # compiles, or loads from the cache
        assert len(_dispatcher(spec).signatures) >= 1, spec
    assert cold_kernels(specs) == []
    # the board variant's warm-up compiled the board specialisation of the LM kernels
    from openemt.solve._model_kernels import is_board

    for spec in ("openemt.solve._lm:lm_batch@board", "openemt.solve._lm:lm_track@board"):
        assert any(is_board(sig[0]) for sig in _dispatcher(spec).signatures), spec


class _FakeIndex:
    """A dispatcher whose numba cache index holds entries of the given signatures."""

    def __init__(self, *sigs):
        index = {(sig, ("magic",), ("hash",)): None for sig in sigs}
        self._cache = types.SimpleNamespace(
            _cache_file=types.SimpleNamespace(_load_index=lambda: index))


def test_a_variant_is_cached_only_with_its_own_specialisation():
    """``lm_batch`` cached for a dipole model is cold for a board (``@board``), and the
    reverse: each specialisation compiles on its own."""
    from numba import types as nt

    from openemt._compile_notice import _is_cached

    array = nt.float64[:, ::1]
    board = nt.Tuple((nt.float64[:, :, ::1], nt.int64[::1]) + (nt.float64[:, ::1],) * 6)
    dipole_only, board_only = _FakeIndex((array, array)), _FakeIndex((board, array))
    assert _is_cached(dipole_only) is True and _is_cached(dipole_only, "board") is False
    assert _is_cached(board_only) is False and _is_cached(board_only, "board") is True
    both = _FakeIndex((array, array), (board, array))
    assert _is_cached(both) is True and _is_cached(both, "board") is True
    assert _is_cached(_FakeIndex()) is False and _is_cached(_FakeIndex(), "board") is False
    with pytest.raises(ValueError, match="expected a kernel variant in"):
        cold_kernels(["openemt.solve._lm:lm_batch@other"])


def test_dipole_kernels_with_and_without_the_cold_start_and_the_complex_check():
    from openemt._compile_notice import COMPLEX_KERNELS, dipole_kernels

    assert dipole_kernels() == SOLVER_KERNELS
    assert dipole_kernels(cold_start_table=True) == SOLVER_KERNELS + COLD_START_KERNELS
    real = dipole_kernels(cold_start_table=True, complex_couplings=False)
    assert real == tuple(k for k in SOLVER_KERNELS + COLD_START_KERNELS
                         if k not in COMPLEX_KERNELS)
    assert COMPLEX_KERNELS and not set(COMPLEX_KERNELS) & set(real)


def test_model_kernels_name_each_models_solver():
    from openemt._compile_notice import model_kernels
    from openemt.board import BoardModel
    from openemt.simulate import get_preset

    assert model_kernels(get_preset("dipole-approx").dipole) == SOLVER_KERNELS
    assert model_kernels(BoardModel.from_board("anser")) == PLANAR_KERNELS
    assert model_kernels(BoardModel.from_board("anser-6dof")) == BOARD_LM_KERNELS
    assert model_kernels(object()) == ()


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
