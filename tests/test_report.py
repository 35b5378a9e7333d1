"""The self-contained HTML report: structure, atomic writing, and rendering in headless Chromium."""

import re

import numpy as np
import pytest
from chromium_render import render

from openemt.report import Report, error_histogram_figure, error_vector_figure, sweep_figure


def make_report(tmp_path):
    rng = np.random.default_rng(0)
    r = Report("openemt test report")
    r.heading("Accuracy").table(
        [{"row": "default", "trans_rms_mm": 0.41555, "rot_rms_deg": 0.27262},
         {"row": "corrected", "trans_rms_mm": 0.26306, "rot_rms_deg": 0.27262}],
        caption="Table II style", digits=5)
    r.figure(error_vector_figure(rng.normal(scale=0.05, size=(60, 3)),
                                 rng.normal(scale=1e-3, size=(60, 3))), "error vectors")
    r.figure(error_histogram_figure(np.abs(rng.normal(size=200)) * 1e-3,
                                    np.abs(rng.normal(size=200)) * 1e-3), "histograms")
    x = np.linspace(-50, 50, 201)
    r.figure(sweep_figure({"X": {"position": x, "panels": {"direct error (mm)": np.abs(x) * 1e-3}},
                           "Y": {"position": x, "panels": {"direct error (mm)": x ** 2 * 1e-5}}}),
             "sweeps")
    path = tmp_path / "report.html"
    r.write(path)
    return path


def test_report_is_self_contained(tmp_path):
    path = make_report(tmp_path)
    text = path.read_text()
    assert text.startswith("<!DOCTYPE html>")
    assert text.count("data:image/png;base64,") == 3
    assert "0.41555" in text and "Table II style" in text
    # nothing is loaded from outside the file
    assert not re.search(r'(src|href)="(https?:|file:|//)', text)
    assert [p.name for p in tmp_path.iterdir()] == ["report.html"]


def test_report_write_failure_leaves_no_file(tmp_path):
    r = Report("x")
    with pytest.raises(FileNotFoundError, match="expected an existing folder"):
        r.write(tmp_path / "missing" / "r.html")
    assert not (tmp_path / "missing").exists()


def test_report_renders_in_chromium(tmp_path):
    path = make_report(tmp_path)
    n_images, n_decoded, dom = render(path, tmp_path)
    assert (n_images, n_decoded) == (3, 3), f"images total/decoded = {n_images}/{n_decoded}"
    assert "openemt test report" in dom

def test_atomic_output_has_ordinary_permissions(tmp_path):
    from openemt import _atomic
    from openemt.io import atomic_path

    with atomic_path(tmp_path / "out.txt") as tmp:
        tmp.write_text("x")
    assert (tmp_path / "out.txt").stat().st_mode & 0o777 == 0o666 & ~_atomic._UMASK
