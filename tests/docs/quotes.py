"""Messages the pages quote, and how a quote is compared with what the code prints.

A quote is a message as a page gives it: a line of a code block (``error: my.toml: ...``)
or a code span (``serial device PATH is gone (...)``). Pages write ``...`` (or ``(...)``)
where they leave text out, and some words stand for a value of the run (``PATH``, ``1234``):
a quote's ``wild`` words. Both sides are compared with their whitespace collapsed (pages
wrap lines): the quote, as a pattern, must occur in what the command printed.

``candidates(text)`` finds what looks like a quoted message on a page, so that a new one
cannot go unchecked: a code-block line starting with ``error:``, ``warning:``, ``PROBLEM:``,
``STATUS=`` or a config file's path and a colon (``/etc/motorctl.toml: ...``), and a code
span holding ``; fix:``, ``; accepted:`` or starting with one of those words.

Pure: text in, text out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from tests.support import REPO

PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]

_STARTS = ("error: ", "warning: ", "PROBLEM: ", "STATUS=")
_CONFIG_PATH = re.compile(r"^(?:[\w./-]+/)?[\w.-]+\.toml: ")
_SPAN = re.compile(r"(?<!`)`([^`]+)`(?!`)")
_FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.M | re.S)


@dataclass(frozen=True)
class Quote:
    """A message quoted on ``page`` (a path from the repository's root), produced by the
    run named ``run``; ``wild``: words of it that stand for any value."""

    page: str
    text: str
    run: str
    wild: tuple[str, ...] = ()

    def pattern(self) -> re.Pattern[str]:
        """The quote as a pattern over collapsed text."""
        text = squash(self.text)
        parts = re.split(r"(\.\.\.)", text)
        out = []
        for part in parts:
            if part == "...":
                out.append(".*?")
                continue
            piece = re.escape(part)
            for word in self.wild:
                piece = re.sub(rf"(?<![\w.]){re.escape(re.escape(word))}(?![\w])", r"\\S+?", piece)
            out.append(piece)
        return re.compile("".join(out))

    def found_in(self, output: str) -> bool:
        return self.pattern().search(squash(output)) is not None


def squash(text: str) -> str:
    """``text`` with every run of white space one space (pages wrap their lines)."""
    return " ".join(text.split())


def looks_like_a_message(text: str) -> bool:
    text = text.strip()
    if text in _STARTS or text + " " in _STARTS:
        return False  # the word alone (``STATUS=``), not a message
    return (
        text.startswith(_STARTS)
        or _CONFIG_PATH.match(text) is not None
        or "; fix:" in text
        or "; accepted:" in text
    )


def candidates(text: str) -> list[str]:
    """What looks like a quoted message in a page's ``text`` (see the module's doc)."""
    found = []
    for block in _FENCE.findall(text):
        for line in block.splitlines():
            line = line.strip().lstrip("#").strip()
            if looks_like_a_message(line):
                found.append(line)
    prose = _FENCE.sub("", text)
    for span in _SPAN.findall(prose.replace("\n", " ")):
        if looks_like_a_message(span):
            found.append(span)
    return found


def on_page(quote: Quote) -> bool:
    return squash(quote.text) in squash((REPO / quote.page).read_text(encoding="utf-8"))


def rel(path: Path) -> str:
    return str(path.relative_to(REPO))
