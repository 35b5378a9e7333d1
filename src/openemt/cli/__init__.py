"""The ``openemt`` command: a thin layer that parses, calls the library and prints.

Each command module exposes ``register(subparsers)``, whose parser sets ``func(args) -> int``;
:func:`main` turns bad input (``ValueError``/``OSError``) into one ``error:`` line and exit 2.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import os
import re
import signal
import sys
import threading
import traceback

from .. import __version__

__all__ = ["build_parser", "main"]

#: Commands in the order of ``openemt --help``: name -> (module ``openemt.cli._<module>``,
#: one-line help), here once, so that ``--help`` lists them without importing any.
COMMANDS = {
    "demo": ("demo", "simulate, calibrate, solve, correct and report (no hardware)"),
    "simulate": ("simulate", "simulate a calibration/test data collection with known truth"),
    "import": ("import_", "import acquisition files into an openemt dataset (.h5)"),
    "calibrate": ("calibrate", "fit a dipole-model and fixture calibration to a dataset"),
    "solve": ("solve", "solve sensor poses from a dataset's couplings"),
    "correct": ("correct", "fit or apply an output correction of poses"),
    "align": ("align", "solve AX = YB between two pose recordings and write pose pairs"),
    "pivot": ("pivot", "pivot calibration: a tracked tool's tip offset and pivot point"),
    "spin": ("spin", "spin calibration: a tracked tool's axis"),
    "register": ("register", "paired-point registration with FRE and predicted TRE"),
    "assess": ("assess", "accuracy assessment on a machined grid (Hummel et al. 2005)"),
    "points": ("points", "points from the dwells of a recorded log, as 3D Slicer markups"),
    "track": ("track",
              "live tracking: raw samples -> couplings -> poses -> OpenIGTLink (Slicer)"),
    "view": ("view", "live view in the browser of a session log or a raw recording"),
    "collect": ("collect", "collect couplings at reference poses (robot, optical tracker)"),
    "info": ("info", "summarise any file openemt writes (dataset, poses, calibration, ...)"),
    "report": ("report", "write a self-contained HTML calibration and characterization report"),
    "reproduce": ("reproduce", "reproduce a table of MacLachlan et al. 2025 from raw data"),
    "devices": ("devices", "list sound cards, serial ports and network ADCs to track from"),
    "design": ("design", "design a tracker: accuracy maps and board layout optimisation"),
    "datasets": ("datasets", "list (and verify) the bundled data sets"),
    "bench": ("bench", "run a benchmark and print its JSON summary"),
}

#: The path a new user follows, and where each step is documented (``openemt --help``).
WORKFLOW = """\
the workflow (docs/workflow.md runs it end to end on the simulator; openemt demo shows it in
one command):
  1. simulate | import   couplings at known poses          docs/simulator.md, docs/data-format.md
  2. calibrate           fit the tracker's model           docs/calibration.md
  3. solve               poses from couplings              docs/solve.md
  4. correct             output correction of poses        docs/correction.md
  5. pivot | register    tool tip and image registration   docs/navigation.md
  6. track               live poses to 3D Slicer           docs/live.md
Every command explains itself with --help; README.md lists all of them and the docs.
"""

_MARKUP = re.compile(r":\w+:`~?([^`]*)`|``([^`]*)``|`([^`]*)`")


def plain_text(text: str) -> str:
    """``text`` without reST markup: ``:func:`x``` and ````x```` become ``x``."""
    return _MARKUP.sub(lambda m: next(g for g in m.groups() if g is not None), text)


class _UsageError(Exception):
    """An argparse error, reported by :func:`main` (one line with the right usage, exit 2)."""

    def __init__(self, parser, message):
        super().__init__(message)
        self.parser = parser


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise _UsageError(self, message)

    def format_help(self):
        return plain_text(super().format_help())


def _command_parsers(parser, argv):
    """The parsers a command line walks through: ``openemt``, the command, a sub-command."""
    chain = [parser]
    for word in argv:
        subs = [a for a in chain[-1]._actions if isinstance(a, argparse._SubParsersAction)]
        if subs and word in subs[0].choices:
            chain.append(subs[0].choices[word])
    return chain


def _is_known(word, parser) -> bool:
    """Whether option ``word`` is one ``parser`` takes (exactly, or as argparse's unique prefix
    of a long option); a negative number counts as a value."""
    name = word.split("=", 1)[0]
    if name in parser._option_string_actions or parser._negative_number_matcher.match(word):
        return True
    if not name.startswith("--"):
        return len(name) > 2 and name[:2] in parser._option_string_actions  # -ofile
    return sum(o.startswith(name) for o in parser._option_string_actions) == 1


def _friendly(exc: _UsageError, parser, argv) -> tuple[argparse.ArgumentParser, str]:
    """The parser whose usage to show and the message: a misspelt option or command is named
    first, with the closest match, whatever else argparse noticed."""
    chain = _command_parsers(parser, argv)
    last = chain[-1]
    if len(chain) > 1:
        for word in argv:
            if word == "--":
                break
            if word.startswith("-") and len(word) > 1 and not _is_known(word, last) \
                    and not (last is not parser and _is_known(word, parser)):
                name = word.split("=", 1)[0]
                close = difflib.get_close_matches(name, list(last._option_string_actions), 1,
                                                  0.6)
                hint = f" (did you mean {close[0]}?)" if close else ""
                return last, f"unrecognized option {name}{hint}"
    subs = [a for a in last._actions if isinstance(a, argparse._SubParsersAction)]
    message = str(exc)
    if subs and "invalid choice" in message:
        words = [w for w in argv if not w.startswith("-")]
        depth = len(chain) - 1
        if len(words) > depth:
            close = difflib.get_close_matches(words[depth], list(subs[0].choices), 1, 0.6)
            if close:
                message += f" (did you mean {close[0]}?)"
    return (exc.parser if len(chain) == 1 else last), message


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``openemt`` argument parser, with only ``command``'s module configured (every
    command's with ``None``, none with ``""``: enough for ``--help`` and ``--version``)."""
    parser = _Parser(prog="openemt", description="Open software stack for electromagnetic "
                     "trackers.", epilog=WORKFLOW, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"openemt {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name, (module, help_) in COMMANDS.items():
        if command is None or command == name:
            mod = importlib.import_module(f"openemt.cli._{module}")
            mod.register(sub)
            # the description: the module docstring's whole first paragraph (a shorter one
            # given is a line of it cut short)
            first = (mod.__doc__ or "").split("\n\n")[0]
            if (sub.choices[name].description or "") in first:
                sub.choices[name].description = " ".join(first.split())
            _describe(sub.choices[name])
        else:
            sub.add_parser(name, help=help_, add_help=False)
    return parser


def _describe(parser) -> None:
    """Give every sub-command of ``parser`` without a description its one-line help as one."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                sub = action.choices[choice.dest]
                if not sub.description and choice.help:
                    sub.description = choice.help[0].upper() + choice.help[1:] + "."
                _describe(sub)


def _command_of(argv) -> str:
    """The command named on a command line (the first word that is not an option), or ''."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else ""
        if word in ("-h", "--help", "--version"):
            return ""
    return ""


#: Argument destinations that name files or folders a command writes.
OUTPUT_DESTS = ("output", "output_dir", "log", "save_raw", "truth_calibration", "figure")


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: handled exactly like Ctrl-C (temporary files are removed, a live session
    ends and writes its log)."""


def _on_sigterm(signum, frame):
    raise Terminated()


def _paths(value):
    if isinstance(value, (str, os.PathLike)):
        yield value
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _paths(v)


def check_outputs(args) -> None:
    """Refuse, before the command runs, outputs that would overwrite an input (any other
    existing path on the command line) or that :func:`openemt._atomic.check_outputs` refuses."""
    from .._atomic import check_outputs as check

    named = {("-o" if d == "output" else "--" + d.replace("_", "-"))
             + (f" ({k + 1})" if k else ""): out
             for d in OUTPUT_DESTS for k, out in enumerate(_paths(getattr(args, d, None)))}
    if not named:
        return
    inputs = [v for d, val in vars(args).items() if d not in OUTPUT_DESTS
              for v in _paths(val) if os.path.exists(v)]
    check(named, inputs, folders=("--output-dir",))


def main(argv=None) -> int:
    """Run the CLI; returns the exit status: 0 ok, 2 bad input (``ValueError``, ``OSError``:
    one ``error:`` line), 1 a bug (its traceback and an invitation to report it), 130/143
    interrupted/terminated."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    command = _command_of(argv)
    if not command and argv and not argv[0].startswith("-"):
        command = None  # an unknown command: configure all, to suggest the closest one
    parser = build_parser(command)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    except _UsageError as exc:
        shown, message = _friendly(exc, parser, argv)
        shown.print_usage(sys.stderr)
        print(f"error: {message}", file=sys.stderr)
        return 2
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        check_outputs(args)
        return int(args.func(args) or 0)
    except Terminated:
        print("error: terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        msg = " ".join(str(exc).split()) or type(exc).__name__
        print(f"error: {msg}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - a bug: shown with its traceback, never as bad input
        traceback.print_exc()
        print("error: internal error: this is a bug in openemt, not a problem with your input; "
              "please report it with the traceback above", file=sys.stderr)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
