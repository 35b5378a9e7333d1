"""The self-contained HTML report: structure, atomic writing, and rendering in headless Chromium."""

import re
import shutil
import subprocess

import numpy as np
import pytest

from openemt.report import Report, error_histogram_figure, error_vector_figure, sweep_figure

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]

# appended to a copy of the page: after load, record how many images decoded with a real size
_PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute('data-images', imgs.length + '/' + ok);
});
</script>"""


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
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.fail("headless Chromium is required for this test (Debian package `chromium`; "
                    ".ci/run installs it)")
    path = make_report(tmp_path)
    probe = tmp_path / "probe.html"
    probe.write_text(path.read_text().replace("</body>", _PROBE + "</body>"))
    out = subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                          "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    m = re.search(r'data-images="(\d+)/(\d+)"', out.stdout)
    assert m is not None, "the page did not finish loading in Chromium"
    assert m.group(1) == "3" and m.group(2) == "3", f"images total/decoded = {m.groups()}"
    assert "openemt test report" in out.stdout


def test_atomic_output_has_ordinary_permissions(tmp_path):
    from openemt.io import _atomic, atomic_path

    with atomic_path(tmp_path / "out.txt") as tmp:
        tmp.write_text("x")
    assert (tmp_path / "out.txt").stat().st_mode & 0o777 == 0o666 & ~_atomic._UMASK
