"""Inline Markdown as a reader sees it: rendered by a CommonMark parser in the HTML report, plain in the
terminal's help (no raw backticks anywhere a user reads)."""

from __future__ import annotations

import argparse

from edofproj.cli import build_parser
from edofproj.reporting.document import Paragraph, Report, Table
from edofproj.reporting.markdown import inline_html, terminal_text


def test_code_spans_bold_and_raw_html_in_the_report_html():
    assert inline_html("run `edofproj demo --quick` now") == "run <code>edofproj demo --quick</code> now"
    # reStructuredText's double backticks are a code span with a double fence; a backtick inside stays
    assert inline_html("``a `b` c``") == "<code>a `b` c</code>"
    assert inline_html("**best** & <script>") == "<b>best</b> &amp; &lt;script&gt;"
    assert inline_html("`<b>`") == "<code>&lt;b&gt;</code>"  # code is escaped, never markup
    assert inline_html("I* = project(I, p_z)") == "I* = project(I, p_z)"  # a lone star is no emphasis


def test_the_html_report_renders_code_and_keeps_the_markdown_as_written(tmp_path):
    report = Report("R")
    report.extend([Paragraph("see `scene_metrics.csv`: it holds"), Table(["m", "x"], [["`doe+net`", "1.0"]])])
    report.write(tmp_path / "r.md", tmp_path / "r.html")
    html = (tmp_path / "r.html").read_text()
    body = html[html.index("<body>") :]
    assert "`" not in body
    assert "<code>scene_metrics.csv</code>" in body and "<code>doe+net</code>" in body
    assert '<span class="pass">holds</span>' in body
    markdown = (tmp_path / "r.md").read_text()
    assert "see `scene_metrics.csv`: it holds" in markdown and "| `doe+net` | 1.0 |" in markdown


def test_terminal_text_drops_code_fences_and_nothing_else():
    assert terminal_text("``edofproj summarize``: mean ± spread") == "edofproj summarize: mean ± spread"
    assert (
        terminal_text("use `--set a=b` on *.png and *.jpg, not **x**") == "use --set a=b on *.png and *.jpg, not **x**"
    )
    assert terminal_text("a\\b, [link](x)") == "a\\b, [link](x)"


def _parsers(parser: argparse.ArgumentParser, name: str = "edofproj"):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, child in action.choices.items():
                yield from _parsers(child, f"{name} {sub}")


def test_no_help_text_shows_a_backtick():
    parsers = list(_parsers(build_parser()))
    assert len(parsers) > 20  # every command and subcommand
    for name, parser in parsers:
        assert "`" not in parser.format_help(), name
    # the descriptions are written with code spans: the terminal shows their content
    summarize = dict(parsers)["edofproj summarize"]
    assert summarize.format_help().count("edofproj summarize: mean ± spread") == 1
