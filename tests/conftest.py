"""Shared test fixtures. Real-data tests read ../shared/data through ``ilemt_dir``."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_REPO = Path(__file__).resolve().parents[1]
_DEFAULT_SHARED = _REPO.parent / "shared"


def _shared_root() -> Path:
    return Path(os.environ.get("OPENEMT_SHARED", _DEFAULT_SHARED))


@pytest.fixture(scope="session")
def ilemt_dir() -> Path:
    """The real ILEMT "concentric source" folder cal_9_15_premo_cmu (read-only)."""
    d = _shared_root() / "data" / "ilemt" / "cal_9_15_premo_cmu"
    if not d.is_dir():
        pytest.fail(f"real data folder missing: {d} (set OPENEMT_SHARED to the shared folder)")
    return d
