"""The minimum versions CI installs (.ci/minimum-versions.txt) are exactly the lower bounds
pyproject.toml declares, so the declared minimums are the tested ones."""

import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bounds(requirements):
    out = {}
    for req in requirements:
        m = re.fullmatch(r"([A-Za-z0-9_.-]+)(\[[^\]]*\])?\s*>=\s*([0-9][^,;\s]*)", req.strip())
        assert m, f"expected 'name>=version' in pyproject.toml, got {req!r}"
        out[m[1].lower()] = m[3]
    return out


def test_ci_installs_the_declared_minimums():
    pins = ROOT / ".ci" / "minimum-versions.txt"
    if not pins.exists():
        pytest.skip("not a source checkout")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = _bounds(project["dependencies"] + project["optional-dependencies"]["test"])
    pinned = {}
    for line in pins.read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            m = re.fullmatch(r"([A-Za-z0-9_.-]+)(\[[^\]]*\])?==(\S+)", line)
            assert m, f"expected 'name==version' in {pins.name}, got {line!r}"
            pinned[m[1].lower()] = m[3]
    assert set(pinned) == set(declared)
    for name, low in declared.items():
        want = low + ".0" * (3 - low.count(".") - 1)
        assert pinned[name] == want, f"{name}: pyproject says >={low}, CI installs {pinned[name]}"
