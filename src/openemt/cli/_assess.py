"""``openemt assess``: thin layer over :func:`openemt.navigate.assess` (options:
:class:`openemt.navigate.AssessOptions`); ``-o`` writes the HTML report of the result."""

from __future__ import annotations

from ._navcommon import step

__all__ = ["register"]


def _report(args, run) -> None:
    if args.output:
        from ..report import assessment_document

        assessment_document(run.result, measured=str(args.measured),
                            nominal=run.summary["nominal"]).write(args.output)


register = step("assess", "AssessOptions", "assess", after=_report)
