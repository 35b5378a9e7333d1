"""``openemt datasets``: list the data sets bundled with openemt, and verify their checksums."""

from __future__ import annotations

from . import command_help
from ._common import add_common, emit

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser("datasets", help=command_help("datasets"),
                       description=__doc__.splitlines()[0])
    p.add_argument("name", nargs="?", help="one data set (default: all)")
    p.add_argument("--verify", action="store_true",
                   help="check every file against its recorded SHA-256 (exit 1 on a mismatch)")
    add_common(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import datasets

    chosen = [args.name] if args.name else datasets.names()
    entries = []
    bad = 0
    for name in chosen:
        entry = datasets.info(name).to_dict()
        if args.verify:
            checks = datasets.verify(name)
            problems = {k: v for k, v in checks.items() if v != "ok"}
            entry["files_checked"] = len(checks)
            entry["problems"] = problems
            bad += len(problems)
        entries.append(entry)
    human = []
    for e in entries:
        human.append(f"{e['name']}: {e['path']}")
        human.append(f"  {e['description']} ({e['license']}; cite {e['citation']})")
        if args.verify:
            state = "all files match" if not e["problems"] else f"PROBLEMS: {e['problems']}"
            human.append(f"  {e['files_checked']} files checked: {state}")
    emit(args, {"datasets": entries, "ok": bad == 0}, human)
    return 1 if bad else 0
