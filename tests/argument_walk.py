"""Walk of `openemt track`'s arguments through the code, dynamically.

Every value given on the command line (and the options record) is followed: a call that receives
one as a parameter is a hop; what a function returns after receiving one is followed too (derived
values: the tracker read from --tracker, ...). A hop is a "stay" (the caller's package is the
callee's), "down" (a lower layer in README's architecture order) or "up"; a hop is also a "climb"
when the value had gone down to a lower package (passed in, or returned from there) and is handed
on by a higher one: the value climbed back up and went down again."""
import re
import sys
from collections import Counter
from pathlib import Path

import openemt

SRC = Path(openemt.__file__).resolve().parent
README = SRC.parents[1] / "README.md"
table = README.read_text().split("## Architecture", 1)[1].split("\n## ", 1)[0]
ORDER = re.findall(r"^\| `openemt\.(\w+)` \|", table, flags=re.M)
RANK = {p: k for k, p in enumerate(ORDER)}
RANK[""] = -1          # openemt._atomic, _errors, ...: below every package


def package(frame):
    mod = frame.f_globals.get("__name__", "")
    if not mod.startswith("openemt"):
        return None
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in RANK else ""


def _followable(v):
    return v is not None and not isinstance(v, bool) and \
        not (isinstance(v, int) and -5 <= v <= 256) and not (isinstance(v, str) and len(v) < 2)


def walk(argv):
    from openemt import cli
    parser = cli.build_parser("track")
    args = parser.parse_args(["track", *argv])
    given = {k: v for k, v in vars(args).items() if k != "func" and _followable(v)}
    keys = {id(v): k for k, v in given.items()}
    keep = list(given.values())
    where = {}            # id -> package where the value was last (received or produced)
    receivers = {}        # id(frame) -> key of a followed value it received
    hops, names = [], set()

    def prof(frame, event, arg):
        if event == "return":
            key = receivers.pop(id(frame), None)
            if key is not None and _followable(arg) and id(arg) not in keys \
                    and package(frame) is not None and type(arg).__module__ != "builtins":
                keys[id(arg)] = key + "*"
                where[id(arg)] = package(frame)
                keep.append(arg)
            return
        if event != "call":
            return
        callee = package(frame)
        back = frame.f_back
        if callee is None or back is None or package(back) is None:
            return
        caller = package(back)
        code = frame.f_code
        for pname in code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]:
            if pname in ("self", "cls"):      # a method called on the value uses it, not hands it on
                continue
            v = frame.f_locals.get(pname)
            if type(v).__name__ == "TrackOptions" and id(v) not in keys:
                keys[id(v)] = "<options>"
                keep.append(v)
            key = keys.get(id(v))
            if key is None:
                continue
            kind = "stay" if callee == caller else ("down" if RANK[callee] < RANK[caller] else "up")
            last = where.get(id(v))
            climb = last is not None and RANK[caller] > RANK[last]
            where[id(v)] = callee
            receivers[id(frame)] = key.rstrip("*")
            hops.append((key, kind, climb, f"{back.f_globals['__name__']}.{back.f_code.co_name}",
                         f"{frame.f_globals['__name__']}.{code.co_name}", pname))
            names.add((frame.f_globals["__name__"], code.co_name, pname))

    sys.setprofile(prof)
    try:
        rc = args.func(args)
    finally:
        sys.setprofile(None)
    return rc, hops, names


if __name__ == "__main__":
    argv = sys.argv[1:]
    rc, hops, names = walk(argv)
    hops = list(dict.fromkeys(hops))          # distinct edges (a loop's repeats count once)
    kinds = Counter(h[1] for h in hops)
    climbs = [h for h in hops if h[2]]
    print(f"rc={rc} distinct hops={len(hops)} {dict(kinds)} climbs={len(climbs)} names={len(names)}")
    for h in climbs:
        print("CLIMB", h)
