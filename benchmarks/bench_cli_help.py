"""Wall time of ``edofproj --help`` and of every ``edofproj CMD --help`` (a fresh interpreter each).

Target: <= 1 s each on the 2-core machine. Each command imports its libraries (torch, OpenCV,
trimesh, matplotlib, SciPy) only when it runs; tests/test_cli_help.py checks that no help loads
them, and ``python -X importtime -m edofproj.cli --help`` shows what the rest costs.

    PYTHONPATH=src python benchmarks/bench_cli_help.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

from edofproj.machine import instruction_sets


def command_names() -> list[str]:
    from edofproj.cli import build_parser

    parser = build_parser()
    names: list[str] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            names += sorted(action.choices)
    return names


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per command; the median is printed (3)")
    args = parser.parse_args()
    print(f"CPU: {instruction_sets()}")
    print(f"{'command':<32} {'median s':>9} {'max s':>7} {'CPU s':>7}")
    worst = 0.0
    for command in [[]] + [[name] for name in command_names()]:
        times, cpu = [], []
        for _ in range(args.repeats):
            before = os.times()
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "edofproj.cli", *command, "--help"], capture_output=True, check=True)
            times.append(time.perf_counter() - start)
            after = os.times()
            cpu.append(after.children_user + after.children_system - before.children_user - before.children_system)
        worst = max(worst, statistics.median(times))
        label = " ".join(["edofproj", *command, "--help"])
        print(f"{label:<32} {statistics.median(times):9.2f} {max(times):7.2f} {statistics.median(cpu):7.2f}")
    print(f"slowest median: {worst:.2f} s (CPU s: user + system time of the process, what it costs without waiting)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
