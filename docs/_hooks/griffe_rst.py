"""Griffe extension for the API reference: the reStructuredText left in the numpydoc docstrings,
rendered as the Markdown mkdocstrings expects.

The docstrings are numpydoc (sections parsed by griffe) whose inline markup is Sphinx's, as in
python-control: ``:class:`~a.B``` roles, ````code```` literals and simple ``=====`` tables.
Markdown shows a role as its text and a simple table as a paragraph, so this extension rewrites
each docstring before it is parsed: a role becomes its target as code (``B`` for ``~a.B``, the
full name otherwise), and a simple table becomes a preformatted block, as it reads in the source.
The docstrings themselves stay as they are (they are read in terminals and editors too).
"""

from __future__ import annotations

import re
from typing import Any

import griffe

#: A Sphinx role: ``:class:`~pkg.Name```, ``:func:`name```, ``:data:`.relative```.
ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):`(~?)\.?([^`]+)`")
#: The border of a reStructuredText simple table: columns of ``=`` separated by spaces.
TABLE_BORDER = re.compile(r"^\s*=+(?: +=+)+\s*$")


def _role(m: re.Match[str]) -> str:
    target = m.group(2)
    return f"``{target.rsplit('.', 1)[-1] if m.group(1) else target}``"


def _tables(text: str) -> str:
    """Each simple table (three borders: top, under the header, bottom) as a ``text`` block."""
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        borders = [i] if TABLE_BORDER.match(lines[i]) else []
        j = i + 1
        while borders and j < len(lines) and len(borders) < 3:
            if TABLE_BORDER.match(lines[j]):
                borders.append(j)
            elif not lines[j].strip():
                break
            j += 1
        if len(borders) == 3:
            indent = re.match(r"\s*", lines[i]).group(0)  # type: ignore[union-attr]
            out += [f"{indent}```text", *lines[i:borders[2] + 1], f"{indent}```"]
            i = borders[2] + 1
        else:
            out.append(lines[i])
            i += 1
    return "\n".join(out)


def rst_to_markdown(text: str) -> str:
    return _tables(ROLE.sub(_role, text))


class RstToMarkdown(griffe.Extension):
    """Rewrite every docstring's reStructuredText roles and simple tables as Markdown."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = rst_to_markdown(obj.docstring.value)
