"""Writing about scores: the report model and its Markdown and HTML writers, figures, tables, the
paper's claims, and the documents of each command that writes a report.

The layer above :mod:`edofproj.evaluation` (which computes the scores and writes their CSV tables):

* :mod:`.document` -- the report model (headings, paragraphs, lists, tables, figures) written as
  Markdown and as self-contained HTML; :mod:`.markdown` renders its inline Markdown (and the
  command-line help) with a CommonMark parser;
* :mod:`.figures`, :mod:`.psf_plots` -- the plots;
* :mod:`.tables` -- summary and spread tables; :mod:`.claims` -- the paper's claims measured;
  :mod:`.image_checks` -- the per-image checks' sections;
* the documents of each command: :mod:`.writeup` (``evaluate`` and the demo), :mod:`.scenes`
  (``evaluate --scene``), :mod:`.captures` (``procams evaluate``); ``summarize`` prints
  :mod:`.tables` as Markdown.
"""
