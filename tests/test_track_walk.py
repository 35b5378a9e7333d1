"""`openemt track`'s arguments climb back up at most twice (issue: library workflows, a thin
command line): the walk in tests/argument_walk.py follows every value given on the command
line, and what is computed from it, through the calls of a short simulated session."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import argument_walk  # noqa: E402

TRACKER = Path(argument_walk.SRC) / "live" / "trackers" / "simulated-2.toml"


def _walk(tmp_path, *extra):
    argv = ["--tracker", str(TRACKER), "--source", "sim", "--duration", "0.3", "--no-igtl",
            "--quiet", "--seed", "3", "--noise", "1e-6", "--stale-after", "0.7",
            "--process-noise", "2.5", "--filter", "kalman", "--log", str(tmp_path / "log.h5"),
            *extra]
    rc, hops, names = argument_walk.walk(argv)
    assert rc == 0
    return list(dict.fromkeys(hops)), names


def test_track_arguments_climb_back_up_at_most_twice(tmp_path):
    hops, names = _walk(tmp_path)
    climbs = [h for h in hops if h[2]]
    assert len(climbs) <= 2, climbs
    # the walk saw the arguments travel (not vacuous): the options record and the values reach
    # live, signal and the filter
    followed = {h[0].rstrip("*") for h in hops}
    assert {"<options>", "tracker", "noise", "process_noise", "stale_after"} <= followed
    assert any(h[4].startswith("openemt.signal.") for h in hops)
    assert len(names) > 20


def test_the_walk_sees_a_climb():
    """A value handed down, returned up and handed down again from above is a climb: a command
    layer that builds the options record, then hands one of its values down again."""
    import openemt.cli._common as common

    namespace = {"__name__": "openemt.cli._walk_probe", "original": common.options_from}
    exec("def options_twice(cls, args, **values):\n"
         "    o = original(cls, args, **values)\n"
         "    if cls.__name__ == 'TrackOptions':\n"
         "        cls(stale_after=o.stale_after)\n"
         "    return o\n", namespace)
    common.options_from = namespace["options_twice"]
    try:
        rc, hops, _ = argument_walk.walk(["--source", "sim", "--duration", "0.2", "--no-igtl",
                                          "--quiet", "--stale-after", "0.7"])
    finally:
        common.options_from = namespace["original"]
    assert rc == 0
    assert any(h[2] and h[0] == "stale_after" for h in hops)
