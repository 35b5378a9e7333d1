"""``openemt collect``: record a reference-pose dataset from a tracker source and a reference
(OpenIGTLink client, CSV with time stamps, or a simulated robot / optical tracker) for
``openemt calibrate --mode reference``; the workflow is :func:`openemt.collect.collect`."""

from __future__ import annotations

import sys

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from ..collect import CollectOptions
    from ..view import ViewOptions
    from ._common import add_command

    add_command(
        subparsers, "collect", run, (CollectOptions, ViewOptions),
        description="Acquire couplings from a tracker source while reference poses arrive "
                    "(an OpenIGTLink server such as PLUS or 3D Slicer, a CSV with time stamps, "
                    "or a simulated robot / optical tracker served over OpenIGTLink); estimate "
                    "the time offset of the two clocks, average both streams over the dwells "
                    "where both are static, check that they pair, and write a dataset for "
                    "'openemt calibrate --mode reference' (docs/reference-calibration.md"
                    "#collecting). Stops at --n-poses, --duration, the end of the source or "
                    "reference, or on Ctrl-C, writing what it has.")


def run(args) -> int:
    from ..collect import CollectOptions, collect
    from ..view import ViewOptions, collect_with_view
    from ._common import emit, options_from

    options = options_from(CollectOptions, args)
    view = options_from(ViewOptions, args)
    progress = None if args.quiet else sys.stderr
    if view.view:                                 # the live view in the browser
        res = collect_with_view(options, view, progress=progress, handle_signals=True)
    else:
        res = collect(options, progress=progress, handle_signals=True)
    human = [f"collected {res.n_poses} poses of sensor {res.sensor!r} -> {res.path} (time "
             f"offset {res.time_offset_ms:.1f} ms, {res.dwells['tracker_dwells']} tracker and "
             f"{res.dwells['reference_dwells']} reference dwells; ended by {res.ended_by})"]
    if res.reference_dropped:
        human.append("reference poses dropped, by reason: " + ", ".join(
            f"{k} {v}" for k, v in res.reference_dropped.items()))
    emit(args, res.to_dict(), human)
    return res.exit_code
