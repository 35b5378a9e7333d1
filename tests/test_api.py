"""The top-level API: main objects reachable from ``import openemt``, loaded on first use."""

import subprocess
import sys

import pytest

import openemt


def test_import_openemt_loads_no_numeric_stack():
    code = ("import sys, openemt; "
            "print(sorted(m for m in ('numpy', 'scipy', 'numba', 'h5py') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=False)
    assert out.stdout.strip() == "[]", out.stderr


@pytest.mark.parametrize("name", sorted(set(openemt.__all__) - {"__version__"}))
def test_every_public_name_resolves(name):
    assert getattr(openemt, name) is not None
    assert name in dir(openemt)


def test_names_are_the_subpackages_objects():
    from openemt import io, solve

    assert openemt.Calibration is io.Calibration
    assert openemt.read_dataset is io.read_dataset
    assert openemt.solve_lm is solve.solve_lm
    assert openemt.solve_svd is solve.solve_svd


def test_unknown_name_raises_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        openemt.nope  # noqa: B018


def test_all_lists_exactly_the_lazy_names():
    assert set(openemt.__all__) == {"__version__", *openemt.SUBPACKAGES, *openemt._ATTRIBUTES}


def test_calibration_and_dataset_where_users_look():
    from openemt import calibrate, io

    assert openemt.Calibration is calibrate.Calibration is io.Calibration
    assert openemt.Dataset is calibrate.Dataset is io.Dataset
    assert openemt.fit_calibration is calibrate.fit
    assert not hasattr(calibrate, "calibrate")  # one calibration entry point


@pytest.mark.parametrize("package", [p for p in openemt.SUBPACKAGES if p != "datasets"])
def test_no_library_function_is_named_like_a_test(package):
    import importlib

    module = importlib.import_module(f"openemt.{package}")
    names = [n for n in getattr(module, "__all__", dir(module)) if n.startswith("test")]
    assert names == []
