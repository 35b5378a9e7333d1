"""Every command's and sub-command's ``--help`` is complete plain text: its description ends a
sentence, no help text is cut inside a parenthesis, and no reST markup shows."""

import argparse

from openemt.cli import WORKFLOW, build_parser, main, plain_text


def _parsers(parser, path=("openemt",)):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


def test_every_help_is_complete_plain_text():
    walked = list(_parsers(build_parser()))
    assert len(walked) > 30  # commands and their sub-commands (import, reproduce, bench, ...)
    for path, parser in walked:
        text = parser.format_help()
        name = " ".join(path)
        assert "`" not in text, name
        description = " ".join((parser.description or "").split())
        assert description.endswith((".", ".)")), f"{name}: description {description!r}"
        for action in parser._actions:
            help_ = action.help or ""
            assert help_.count("(") == help_.count(")"), f"{name} {action.dest}: {help_!r}"


def test_markup_is_removed_and_the_top_help_lists_the_workflow(capsys):
    assert plain_text("see ``openemt pivot`` and :func:`~openemt.solve.prepare`, `x`") == \
        "see openemt pivot and openemt.solve.prepare, x"
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert WORKFLOW.splitlines()[-1] in out
    steps = [line.split()[1] for line in out.splitlines() if line[:4].strip().rstrip(".").isdigit()]
    assert steps == ["simulate", "calibrate", "solve", "correct", "pivot", "track"]
    for doc in ("docs/workflow.md", "docs/calibration.md", "docs/navigation.md", "README.md"):
        assert doc in out
