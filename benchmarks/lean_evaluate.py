"""``edofproj evaluate`` without its timing stage and with a 2-layer tilted screen: the same flat-screen
``metrics.csv``, ``summary.md`` and report, for a loaded machine where the full evaluation takes too long.

    PYTHONPATH=src python benchmarks/lean_evaluate.py RUN OUT METHODS DEPTHS [--validation] [KEY=VALUE ...]

``KEY=VALUE``: config overrides (e.g. ``evaluation.display_guard=false``). ``METHODS`` comma-separated, ``DEPTHS`` as ``edofproj evaluate --depths-mm`` (``300:800:50``). The
flat-screen scores are those of ``edofproj evaluate`` (same code path); the tilted-screen table is
not comparable (2 depth layers instead of ``imaging.depth_layers``) and ms/frame is absent.
"""

from __future__ import annotations

import sys
import time

import torch

from edofproj.commands._common import parse_number_list
from edofproj.evaluation.pipeline import evaluate_run
from edofproj.machine import instruction_sets
from edofproj.reporting.writeup import write_documents


def depths(text: str) -> list[float]:
    if text.count(":") == 2:
        lo, hi, step = (float(v) for v in text.split(":"))
        count = int(round((hi - lo) / step)) + 1
        return [lo + i * step for i in range(count)]
    return parse_number_list(text, "DEPTHS")


def main() -> None:
    run, out, methods, depth_text = sys.argv[1:5]
    torch.set_num_threads(1)
    clock = time.perf_counter()
    evaluation = evaluate_run(
        run,
        out_dir=out,
        depths_mm=depths(depth_text),
        methods=methods.split(","),
        overrides=["imaging.depth_layers=2", *(arg for arg in sys.argv[5:] if "=" in arg)],
        timing=False,
        validation="--validation" in sys.argv[5:],
    )
    write_documents(evaluation, title=f"lean evaluation of {evaluation.run.run_dir}")
    print(f"{out}: {time.perf_counter() - clock:.0f} s, 1 thread [{instruction_sets()}]")


if __name__ == "__main__":
    main()
