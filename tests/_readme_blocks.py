"""The fenced code blocks of README.md, with the HTML comment marking each (the one way the
README tests extract them)."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"

#: A fenced block of one language, and the HTML comment on the line just before it (if any).
_BLOCK = re.compile(r"(?:<!--\s*(?P<marker>[^\n]*?)\s*-->\n)?```(?P<lang>\w+)\n(?P<code>.*?)```",
                    flags=re.DOTALL)


def readme_blocks(lang: str, text: str | None = None) -> list[tuple[str, str]]:
    """``(marker, code)`` of every ```lang block of the README (marker '' when none)."""
    text = README.read_text() if text is None else text
    return [(m.group("marker") or "", m.group("code")) for m in _BLOCK.finditer(text)
            if m.group("lang") == lang]
