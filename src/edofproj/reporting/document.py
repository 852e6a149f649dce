"""A small document model rendered twice: Markdown (figures as files) and self-contained HTML.

A :class:`Report` is a list of blocks -- headings, paragraphs, bullet lists, tables, figures,
preformatted text. :meth:`Report.to_markdown` links each figure by its path relative to the
Markdown file; :meth:`Report.to_html` embeds each figure as a base64 ``data:`` URI, so the
HTML file is readable on its own (mailed, archived, opened without the project).

Inline text is Markdown (code spans, ``**bold**``, emphasis, links): the Markdown file carries it as
written, the HTML renders it with a CommonMark parser (:func:`.markdown.inline_html`; raw HTML in
a text is escaped, never markup), and the verdict words PASS, FAIL, holds and does not hold are
coloured.
"""

from __future__ import annotations

import base64
import html
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence, Union

from ..fileio import write_text_atomic
from .markdown import inline_html


@dataclass
class Heading:
    """A section heading. ``level`` 2 is a section (level 1 is the report's title): Markdown uses
    ``max(2, level)`` hashes, HTML ``<h2>`` to ``<h4>`` (levels clipped to 2..4)."""

    text: str
    level: int = 2


@dataclass
class Paragraph:
    """A paragraph of inline Markdown."""

    text: str


@dataclass
class Bullets:
    """An unordered list, one inline-text item per bullet."""

    items: list[str]


@dataclass
class Table:
    """A table of text cells: ``header`` (one name per column, none blank), ``rows`` (lists of cells) and an
    optional ``caption`` shown above it. Columns after the first whose cells are all numbers (or ``NA``, ``-``,
    empty) are right-aligned."""

    header: list[str]
    rows: list[list[str]]
    caption: str = ""

    def __post_init__(self) -> None:
        if any(not str(name).strip() for name in self.header):
            raise ValueError(f"every column of a table has a name: {self.header}")


@dataclass
class Figure:
    """A PNG image file with a caption: linked by its path relative to the Markdown file, embedded as a
    base64 ``data:`` URI in the HTML (the file must exist when the HTML is rendered)."""

    path: Path
    caption: str


@dataclass
class Preformatted:
    """Verbatim text (a code block in Markdown, ``<pre>`` in HTML)."""

    text: str


Block = Union[Heading, Paragraph, Bullets, Table, Figure, Preformatted]

_CSS = """
body { font-family: -apple-system, 'Segoe UI', Helvetica, Arial, sans-serif; max-width: 1100px;
       margin: 2em auto; padding: 0 1em; color: #222; line-height: 1.45; }
h1 { border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { border-bottom: 1px solid #bbb; padding-bottom: .15em; margin-top: 1.8em; }
table { border-collapse: collapse; margin: .6em 0 1.2em; font-size: 0.88em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
th { background: #f0f0f0; }
caption { caption-side: top; text-align: left; font-style: italic; padding-bottom: .3em; }
figure { margin: 1em 0 1.6em; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #444; margin-top: .3em; }
code { background: #f2f2f2; padding: 0 .2em; border-radius: 3px; font-size: 0.92em; }
pre { background: #f6f6f6; padding: .6em; overflow-x: auto; font-size: 0.85em; }
.pass { color: #0a7d16; font-weight: bold; }
.fail { color: #c01010; font-weight: bold; }
"""


def _verdict_html(text: str) -> str:
    """Plain text HTML-escaped, with the verdict words coloured (classes ``pass`` and ``fail``)."""
    escaped = html.escape(text)
    for word, style in (("PASS", "pass"), ("FAIL", "fail"), ("does not hold", "fail")):
        escaped = escaped.replace(word, f'<span class="{style}">{word}</span>')
    return re.sub(r"\bholds\b", '<span class="pass">holds</span>', escaped)


def _inline_html(text: str) -> str:
    return inline_html(text, _verdict_html)


def _md_cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def image_data_uri(path: str | Path) -> str:
    """A PNG file as a ``data:image/png;base64,...`` URI."""
    data = Path(path).read_bytes()
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


@dataclass
class Report:
    """A titled list of blocks; ``add`` appends and returns the block."""

    title: str
    blocks: list[Block] = field(default_factory=list)

    def add(self, block: Block) -> Block:
        """Append ``block`` and return it (to keep a handle on a table filled later)."""
        self.blocks.append(block)
        return block

    def extend(self, blocks: Sequence[Block]) -> None:
        """Append ``blocks`` in order."""
        self.blocks.extend(blocks)

    # -- Markdown ----------------------------------------------------------------------
    def to_markdown(self, base_dir: str | Path) -> str:
        """Markdown; figure links relative to ``base_dir`` (where the ``.md`` file goes)."""
        lines = [f"# {self.title}", ""]
        for block in self.blocks:
            lines += _block_markdown(block, Path(base_dir)) + [""]
        return "\n".join(lines).rstrip() + "\n"

    # -- HTML --------------------------------------------------------------------------
    def to_html(self) -> str:
        """One self-contained HTML page (figures embedded as base64 PNG)."""
        body = [f"<h1>{_inline_html(self.title)}</h1>"]
        for block in self.blocks:
            body.append(_block_html(block))
        return (
            '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>{html.escape(self.title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
            + "\n".join(body)
            + "\n</body>\n</html>\n"
        )

    def write(self, markdown_path: str | Path | None = None, html_path: str | Path | None = None) -> None:
        """Write the Markdown and/or the HTML file atomically."""
        if markdown_path is not None:
            write_text_atomic(markdown_path, self.to_markdown(Path(markdown_path).parent))
        if html_path is not None:
            write_text_atomic(html_path, self.to_html())


_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _is_number(cell: str) -> bool:
    text = str(cell).replace("**", "").split(" (")[0].strip()
    return text in ("NA", "-", "") or bool(_NUMBER.match(text))


def _numeric_columns(table: Table) -> list[bool]:
    """Right-align the columns whose cells are all numbers (the first column never)."""
    return [
        index > 0 and all(_is_number(row[index]) for row in table.rows if index < len(row))
        for index in range(len(table.header))
    ]


def _block_markdown(block: Block, base_dir: Path) -> list[str]:
    if isinstance(block, Heading):
        return ["#" * max(2, block.level) + " " + block.text]
    if isinstance(block, Paragraph):
        return [block.text]
    if isinstance(block, Bullets):
        return [f"* {item}" for item in block.items]
    if isinstance(block, Table):
        lines = [f"*{block.caption}*", ""] if block.caption else []
        lines.append("| " + " | ".join(_md_cell(h) for h in block.header) + " |")
        lines.append("|" + "|".join("---:" if numeric else "---" for numeric in _numeric_columns(block)) + "|")
        lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in block.rows]
        return lines
    if isinstance(block, Figure):
        relative = Path(os.path.relpath(Path(block.path).resolve(), base_dir.resolve())).as_posix()
        return [f"![{_md_cell(block.caption)}]({relative})", "", f"*{block.caption}*"]
    if isinstance(block, Preformatted):
        return ["```", block.text.rstrip(), "```"]
    raise TypeError(f"unknown report block {block!r}")


def markdown_table(table: Table) -> str:
    """``table`` as Markdown (its caption in italics above it)."""
    return "\n".join(_block_markdown(table, Path(".")))


def _block_html(block: Block) -> str:
    if isinstance(block, Heading):
        level = min(max(2, block.level), 4)
        return f"<h{level}>{_inline_html(block.text)}</h{level}>"
    if isinstance(block, Paragraph):
        return f"<p>{_inline_html(block.text)}</p>"
    if isinstance(block, Bullets):
        return "<ul>\n" + "\n".join(f"<li>{_inline_html(item)}</li>" for item in block.items) + "\n</ul>"
    if isinstance(block, Table):
        caption = f"<caption>{_inline_html(block.caption)}</caption>" if block.caption else ""
        numeric = _numeric_columns(block)
        head = "<tr>" + "".join(f"<th>{_inline_html(h)}</th>" for h in block.header) + "</tr>"
        rows = "\n".join(
            "<tr>"
            + "".join(
                f'<td style="text-align:{"right" if numeric[i] else "left"}">{_inline_html(str(c))}</td>'
                for i, c in enumerate(row)
            )
            + "</tr>"
            for row in block.rows
        )
        return f"<table>{caption}\n<thead>{head}</thead>\n<tbody>\n{rows}\n</tbody></table>"
    if isinstance(block, Figure):
        return (
            f'<figure><img src="{image_data_uri(block.path)}" alt="{html.escape(block.caption)}">'
            f"<figcaption>{_inline_html(block.caption)}</figcaption></figure>"
        )
    if isinstance(block, Preformatted):
        return f"<pre>{html.escape(block.text)}</pre>"
    raise TypeError(f"unknown report block {block!r}")
