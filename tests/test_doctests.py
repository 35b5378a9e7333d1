"""The ``Examples`` sections of the docstrings run as written (doctest)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import openemt

#: Packages whose every module's examples run here, and single modules besides them.
PACKAGES = ("calibrate", "evaluate", "paper", "report", "signal", "simulate")
MODULES = ("openemt", "openemt.io._calfile", "openemt.io._hdf5", "openemt.io._ilemt",
           "openemt.correct._model", "openemt.solve._closed_form", "openemt.solve._lm_solver",
           "openemt.solve._prepared")


def _modules():
    names = list(MODULES)
    for pkg in PACKAGES:
        module = importlib.import_module(f"openemt.{pkg}")
        names.append(module.__name__)
        names += [m.name for m in pkgutil.iter_modules(module.__path__, f"{module.__name__}.")]
    return names


@pytest.mark.parametrize("name", _modules())
def test_docstring_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in finder.find(module, name, globs={}):
        runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"


def test_the_main_functions_have_examples():
    from openemt import calibrate, signal, simulate

    for func in (openemt.read_dataset, openemt.import_ilemt_folder, openemt.read_calibration,
                 openemt.fit_calibration, openemt.pose_errors, openemt.error_summary,
                 simulate.simulate, simulate.truth_calibration, signal.demodulate,
                 calibrate.solve_held_out, openemt.fit_correction, openemt.solve_lm,
                 openemt.solve_svd, openemt.solve_kuipers, openemt.solve_kim18):
        assert "Examples\n" in (func.__doc__ or ""), func.__qualname__
