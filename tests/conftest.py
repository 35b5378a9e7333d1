"""Shared test fixtures. Real-data tests read the bundled ILEMT folder through ``ilemt_dir``."""

from __future__ import annotations

from pathlib import Path

import pytest

from openemt import datasets


@pytest.fixture(scope="session")
def ilemt_dir() -> Path:
    """The real ILEMT "concentric source" folder cal_9_15_premo_cmu (read-only)."""
    return datasets.path("cal_9_15_premo_cmu")
