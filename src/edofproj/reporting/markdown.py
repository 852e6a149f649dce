"""Inline Markdown rendered by a CommonMark parser (markdown-it-py): for an HTML page and for a terminal.

The texts of a report and of the command-line help are written in Markdown's inline syntax: code
spans (text between backticks; reStructuredText's double backticks are the same span with a
double fence), ``**bold**``, ``*emphasis*``. A report's Markdown file carries them as they are;
the two renderings here turn them into what a reader sees:

* :func:`inline_html` -- HTML of one paragraph of inline Markdown (CommonMark, raw HTML disabled:
  every ``<``, ``>`` and ``&`` of the text is escaped); the text between the markup goes through
  ``text_html`` (default: HTML-escaped), so that a caller can style words of it;
* :func:`terminal_text` -- the same text for a terminal: a code span becomes its content, nothing
  else is read as markup (the ``*`` of ``*.png`` stays).
"""

from __future__ import annotations

import html
from functools import lru_cache
from typing import Callable

from markdown_it import MarkdownIt


@lru_cache(maxsize=None)
def _html_parser() -> MarkdownIt:
    # html=False: raw HTML in a text is text (escaped), never markup
    parser = MarkdownIt("commonmark", {"html": False})
    parser.add_render_rule("strong_open", lambda *args: "<b>")
    parser.add_render_rule("strong_close", lambda *args: "</b>")
    return parser


@lru_cache(maxsize=None)
def _code_span_parser() -> MarkdownIt:
    # the "zero" preset reads nothing but paragraphs and text; code spans are added
    return MarkdownIt("zero").enable("backticks")


def inline_html(text: str, text_html: Callable[[str], str] = html.escape) -> str:
    """``text`` (one paragraph of inline Markdown) as HTML; ``**bold**`` is ``<b>``, a code span
    ``<code>``, and each run of plain text is ``text_html(run)``."""
    parser = _html_parser()
    tokens = parser.parseInline(str(text))
    for token in tokens:
        for child in token.children or ():
            if child.type == "text":
                # rendered as given: html_inline tokens are never produced (html=False)
                child.type, child.content = "html_inline", text_html(child.content)
    return parser.renderer.render(tokens, parser.options, {})


def terminal_text(text: str) -> str:
    """``text`` for a terminal: each code span (single or double backticks) replaced by its content;
    the rest kept as written."""
    tokens = _code_span_parser().parseInline(str(text))
    return "".join(child.content for token in tokens for child in token.children or ())
