"""Data sets that travel with openemt: a small registry of name -> folder, with checksums.

The real ILEMT recording used by the tests, the examples and ``openemt reproduce`` is installed
with the package (``openemt/datasets/<name>/``), so it is found from an installed wheel and from
a source checkout alike; nothing is downloaded.

Examples
--------
>>> from openemt import datasets
>>> datasets.names()
['cal_9_15_premo_cmu']
>>> folder = datasets.path("cal_9_15_premo_cmu")
>>> (folder / "base_calibration.mat").is_file()
True
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

from .._errors import InputError
from .._options import option
from .._result import Result

__all__ = ["DatasetInfo", "DatasetsOptions", "DatasetsResult", "check_datasets", "info", "names",
           "path", "verify"]

_HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class DatasetInfo:
    """One bundled data set.

    Attributes
    ----------
    name : str
        Registry name (also the folder name).
    description : str
        One line on what it holds.
    citation : str
        The publication to credit.
    license : str
        Licence of the data.
    """

    name: str
    description: str
    citation: str
    license: str

    @property
    def path(self) -> Path:
        """Folder of the data set."""
        return _HERE / self.name

    @property
    def checksum_file(self) -> Path:
        """``sha256sum``-format list of the folder's files."""
        return _HERE / f"{self.name}.sha256"

    def to_dict(self) -> dict:
        return {**asdict(self), "path": str(self.path)}


_REGISTRY = {
    "cal_9_15_premo_cmu": DatasetInfo(
        name="cal_9_15_premo_cmu",
        description=("ILEMT 'concentric source' recording: CMU ferrite-cube source, Premo "
                     "3-axis sensor, 6 fixture combinations, md/ld/sweep/source patterns"),
        citation=("MacLachlan, Pelle, Hollis, De Momi, Riviere, 'Calibration and "
                  "Characterization of Electromagnetic Position and Orientation Trackers', "
                  "IEEE Sensors Journal, 2025"),
        license="Apache-2.0",
    ),
}


def names() -> list[str]:
    """Names of the bundled data sets."""
    return sorted(_REGISTRY)


def info(name: str) -> DatasetInfo:
    """Registry entry of a bundled data set (``InputError`` for an unknown name)."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(f"expected a bundled data set name in {names()}, got {name!r}") from None


def path(name: str) -> Path:
    """Folder of a bundled data set.

    Parameters
    ----------
    name : str
        Registry name, see :func:`names`.

    Returns
    -------
    pathlib.Path
        The folder (read it in place; do not write into it).
    """
    folder = info(name).path
    if not folder.is_dir():
        raise InputError(f"expected the bundled data folder {folder}, got nothing there "
                         f"(an incomplete installation?)")
    return folder


def verify(name: str) -> dict[str, str]:
    """Check every file of a data set against its recorded SHA-256.

    Returns
    -------
    dict
        ``{relative path: "ok" | "missing" | "changed"}`` for every recorded file; files present
        but not recorded are listed as ``"unrecorded"``.
    """
    entry = info(name)
    folder = path(name)
    result: dict[str, str] = {}
    for line in entry.checksum_file.read_text().splitlines():
        digest, rel = line.split(maxsplit=1)
        rel = rel.removeprefix("./")
        f = folder / rel
        if not f.is_file():
            result[rel] = "missing"
            continue
        h = hashlib.sha256(f.read_bytes()).hexdigest()
        result[rel] = "ok" if h == digest else "changed"
    for f in sorted(folder.rglob("*")):
        rel = f.relative_to(folder).as_posix()
        if f.is_file() and rel not in result:
            result[rel] = "unrecorded"
    return result


@dataclass(frozen=True)
class DatasetsOptions:
    """Which data sets ``openemt datasets`` lists (field metadata: the command-line help)."""

    name: str | None = option(None, "one data set (default: all)", positional=True,
                              optional=True)
    verify: bool = option(False, "check every file against its recorded SHA-256 (exit 1 on a "
                          "mismatch)")


@dataclass(frozen=True)
class DatasetsResult(Result):
    """The data sets listed and, when verified, their files' problems (``ok``: none)."""

    datasets: list
    ok: bool

    @property
    def exit_status(self) -> int:
        return 0 if self.ok else 1

    def lines(self) -> list[str]:
        """Two lines per data set, a third with the verification."""
        human = []
        for e in self.datasets:
            human += [f"{e['name']}: {e['path']}",
                      f"  {e['description']} ({e['license']}; cite {e['citation']})"]
            if "problems" in e:
                state = "all files match" if not e["problems"] else f"PROBLEMS: {e['problems']}"
                human.append(f"  {e['files_checked']} files checked: {state}")
        return human


def check_datasets(o: DatasetsOptions, say=None) -> DatasetsResult:
    """List the data sets ``o`` names, verifying their checksums with ``o.verify``."""
    entries = []
    for name in [o.name] if o.name else names():
        entry = info(name).to_dict()
        if o.verify:
            checks = verify(name)
            entry["files_checked"] = len(checks)
            entry["problems"] = {k: v for k, v in checks.items() if v != "ok"}
        entries.append(entry)
    return DatasetsResult(entries, not any(e.get("problems") for e in entries))
