"""Root test configuration: the docstring examples under ``src/`` (collected by
``--doctest-modules``, see pyproject.toml) run in a temporary folder, so an example that writes
a file leaves nothing in the checkout."""

from __future__ import annotations

import pytest
from _pytest.doctest import DoctestItem


@pytest.fixture(autouse=True)
def _doctests_in_a_temporary_folder(request, tmp_path, monkeypatch):
    if isinstance(request.node, DoctestItem):
        monkeypatch.chdir(tmp_path)
