"""Build a program of ``tests/cpp`` against Debian's OpenIGTLink C++ library (header version 1),
or skip the test saying what is missing (`.ci/run` installs g++ and libopenigtlink-dev)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

CPP = Path(__file__).parent / "cpp"
INCLUDE_DIRS = [Path("/usr/include/openigtlink"), Path("/usr/local/include/openigtlink")]


def build_cpp(name: str, folder: Path) -> Path:
    """``tests/cpp/<name>.cxx`` compiled into ``folder``; skips when it cannot be built."""
    cxx = shutil.which("g++") or shutil.which("c++")
    if cxx is None:
        pytest.skip(f"no C++ compiler (g++ / c++) found: the OpenIGTLink C++ {name} is not built")
    inc = next((d for d in INCLUDE_DIRS if (d / "igtlServerSocket.h").exists()), None)
    if inc is None:
        pytest.skip("no OpenIGTLink C++ library found (apt-get install libopenigtlink-dev)")
    exe = folder / name
    r = subprocess.run([cxx, "-O1", f"-I{inc}", "-o", str(exe), str(CPP / f"{name}.cxx"),
                        "-lOpenIGTLink"], capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        pytest.skip(f"the OpenIGTLink C++ {name} did not build: {r.stderr.strip()[-300:]}")
    return exe
