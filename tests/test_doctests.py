"""The ``Examples`` sections of the docstrings run as written: pytest collects them from every
module under ``src/openemt`` (``--doctest-modules`` and ``testpaths`` in pyproject.toml, run in a
temporary folder by the root conftest.py). Here: that configuration stays, and the main
functions keep their examples."""

from __future__ import annotations

import tomllib
from pathlib import Path

import openemt

ROOT = Path(__file__).resolve().parents[1]


def test_every_module_docstring_is_collected():
    ini = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert "--doctest-modules" in ini["addopts"].split()
    assert "src/openemt" in ini["testpaths"]


def test_the_main_functions_have_examples():
    from openemt import calibrate, geometry, signal, simulate

    for func in (openemt.read_dataset, openemt.import_ilemt_folder, openemt.read_calibration,
                 openemt.fit_calibration, openemt.pose_errors, openemt.error_summary,
                 simulate.simulate, simulate.truth_calibration, signal.demodulate,
                 calibrate.solve_held_out, openemt.fit_correction, openemt.solve_lm,
                 openemt.solve_svd, openemt.solve_kuipers, openemt.solve_kim18,
                 geometry.rotation_diversity):
        assert "Examples\n" in (func.__doc__ or ""), func.__qualname__
