"""Safe matching of file-name patterns taken from data folders.

ILEMT options files name the files a sign flip applies to with MATLAB regular expressions such
as ``soZoutYup_seYoutZup_(md|ld).dat``. A backtracking regex engine given a crafted pattern
(``(a+)+$``) and file name takes time exponential in the name's length, so openemt never compiles
such text with :mod:`re`. It accepts the small language these files use and matches it with a
linear-time automaton (one pass over the name, a set of pattern positions):

- literal characters, ``\\`` escapes (``\\.``, ``\\d``, ``\\w``, ``\\s``), ``.`` and ``[...]`` classes;
- ``*``, ``+``, ``?`` after any of those;
- ``^`` and ``$`` anchors;
- one level of alternatives ``(a|b|...)`` whose branches hold no groups and are not
  themselves quantified.

Anything else (nested or quantified groups, back-references, look-arounds, ``{m,n}``) is refused
with an :class:`~openemt._errors.InputError`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

from .._errors import InputError

__all__ = ["NamePattern", "compile_name_pattern"]

#: Alternatives expand into at most this many plain patterns.
MAX_EXPANSIONS = 64
#: Longest accepted pattern (characters).
MAX_PATTERN_LENGTH = 256

_CLASSES = {"d": "0123456789", "w": "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
            "0123456789_", "s": " \t\r\n\f\v"}


def _refuse(pattern: str, why: str) -> InputError:
    return InputError(f"expected a file-name regular expression of literals, '.', '[...]', '*', '+', '?', "
                      f"'^', '$' and one level of (a|b) alternatives, got {pattern!r} ({why})")


def _expand(pattern: str) -> list[str]:
    """Split one level of ``(a|b)`` groups into plain alternatives."""
    out = [""]
    i = 0
    while i < len(pattern):
        c = pattern[i]
        if c == "\\":
            piece = pattern[i:i + 2]
            i += 2
            out = [o + piece for o in out]
            continue
        if c == "[":
            j = pattern.find("]", i + 2)
            if j < 0:
                raise _refuse(pattern, "unclosed '['")
            piece = pattern[i:j + 1]
            i = j + 1
            out = [o + piece for o in out]
            continue
        if c == ")":
            raise _refuse(pattern, "unbalanced ')'")
        if c == "(":
            j = pattern.find(")", i)
            if j < 0:
                raise _refuse(pattern, "unclosed '('")
            body = pattern[i + 1:j]
            if "(" in body or "\\" in body or "[" in body:
                raise _refuse(pattern, "groups inside groups or escapes in alternatives")
            if body.startswith("?"):
                raise _refuse(pattern, "look-arounds and special groups")
            if j + 1 < len(pattern) and pattern[j + 1] in "*+?{":
                raise _refuse(pattern, "a quantified group can take exponential time")
            branches = body.split("|")
            if any(ch in b for b in branches for ch in "*+?{"):
                raise _refuse(pattern, "quantifiers inside alternatives")
            out = [o + b for o in out for b in branches]
            if len(out) > MAX_EXPANSIONS:
                raise _refuse(pattern, f"more than {MAX_EXPANSIONS} alternatives")
            i = j + 1
            continue
        out = [o + c for o in out]
        i += 1
    return out


@dataclass(frozen=True)
class _Token:
    chars: frozenset | None  # None: any character
    negate: bool
    repeat: str  # "", "*", "+", "?"

    def accepts(self, ch: str) -> bool:
        if self.chars is None:
            return True
        return (ch in self.chars) != self.negate


def _class(body: str, pattern: str) -> tuple[frozenset, bool]:
    negate = body.startswith("^")
    body = body[1:] if negate else body
    chars = set()
    k = 0
    while k < len(body):
        if k + 2 < len(body) and body[k + 1] == "-":
            lo, hi = body[k], body[k + 2]
            if ord(hi) < ord(lo):
                raise _refuse(pattern, f"bad range {lo}-{hi}")
            chars.update(chr(c) for c in range(ord(lo), ord(hi) + 1))
            k += 3
        else:
            chars.add(body[k])
            k += 1
    return frozenset(chars), negate


def _tokens(plain: str, pattern: str) -> tuple[bool, tuple[_Token, ...], bool]:
    start = plain.startswith("^")
    plain = plain[1:] if start else plain
    end = plain.endswith("$") and not plain.endswith("\\$")
    plain = plain[:-1] if end else plain
    toks: list[_Token] = []
    i = 0
    while i < len(plain):
        c = plain[i]
        if c in "*+?":
            if not toks or toks[-1].repeat:
                raise _refuse(pattern, f"'{c}' without something to repeat")
            toks[-1] = _Token(toks[-1].chars, toks[-1].negate, c)
            i += 1
            continue
        if c in "{}^$|":
            raise _refuse(pattern, f"'{c}' is not supported here")
        if c == "\\":
            if i + 1 >= len(plain):
                raise _refuse(pattern, "trailing '\\'")
            e = plain[i + 1]
            if e.isdigit():
                raise _refuse(pattern, "back-references")
            chars = frozenset(_CLASSES[e]) if e in _CLASSES else frozenset(e)
            toks.append(_Token(chars, False, ""))
            i += 2
        elif c == "[":
            j = plain.find("]", i + 2)
            chars, negate = _class(plain[i + 1:j], pattern)
            toks.append(_Token(chars, negate, ""))
            i = j + 1
        elif c == ".":
            toks.append(_Token(None, False, ""))
            i += 1
        else:
            toks.append(_Token(frozenset(c), False, ""))
            i += 1
    return start, tuple(toks), end


def _closure(states: set, toks) -> set:
    """Add the positions reachable by skipping optional tokens (``*``, ``?``)."""
    stack = list(states)
    while stack:
        s = stack.pop()
        if s < len(toks) and toks[s].repeat in ("*", "?") and s + 1 not in states:
            states.add(s + 1)
            stack.append(s + 1)
    return states


@dataclass(frozen=True)
class NamePattern:
    """A compiled safe pattern; :meth:`search` behaves like ``re.search`` on the language."""

    pattern: str
    alternatives: tuple

    def search(self, name: str) -> bool:
        return any(self._search_one(alt, name) for alt in self.alternatives)

    @staticmethod
    def _search_one(alt, name: str) -> bool:
        start, toks, end = alt
        n = len(toks)
        states = _closure({0}, toks)
        if n in states and not end:
            return True
        for ch in name:
            nxt = set()
            for s in states:
                if s < n and toks[s].accepts(ch):
                    nxt.add(s + 1)
                    if toks[s].repeat in ("*", "+"):
                        nxt.add(s)
            if not start:
                nxt.add(0)  # unanchored: a match may begin at every character
            states = _closure(nxt, toks)
            if n in states and not end:
                return True
        return n in states


@functools.lru_cache(maxsize=256)
def compile_name_pattern(pattern: str) -> NamePattern:
    """Compile a file-name pattern of the safe language (see the module docstring).

    Examples
    --------
    >>> p = compile_name_pattern("soZoutYup_seYoutZup_(md|ld).dat")
    >>> p.search("soZoutYup_seYoutZup_ld.dat"), p.search("soZoutYup_seYoutZup_sweep.dat")
    (True, False)
    """
    if not isinstance(pattern, str):
        raise InputError(f"expected a file-name pattern string, got {type(pattern).__name__}")
    if len(pattern) > MAX_PATTERN_LENGTH:
        raise _refuse(pattern[:40] + "...", f"longer than {MAX_PATTERN_LENGTH} characters")
    alts = tuple(_tokens(p, pattern) for p in _expand(pattern))
    return NamePattern(pattern, alts)
