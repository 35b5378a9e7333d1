"""Render an HTML file in headless Chromium (Debian's ``chromium``) for the report tests."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

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


def render(path, tmp_path):
    """Load the page in headless Chromium; returns (n images, n decoded, DOM text)."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.fail("headless Chromium is required for this test (Debian package `chromium`; "
                    ".ci/run installs it)")
    probe = tmp_path / "probe.html"
    probe.write_text(path.read_text().replace("</body>", _PROBE + "</body>"))
    out = subprocess.run([chromium, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                          "--virtual-time-budget=10000", "--dump-dom", probe.as_uri()],
                         capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    m = re.search(r'data-images="(\d+)/(\d+)"', out.stdout)
    assert m is not None, "the page did not finish loading in Chromium"
    return int(m.group(1)), int(m.group(2)), out.stdout
