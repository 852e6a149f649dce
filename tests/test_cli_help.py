"""``edofproj --help`` and every ``edofproj CMD --help`` load no heavy library (torch, OpenCV,
trimesh, matplotlib, SciPy): each command imports its library only when it runs. Their times
are measured by benchmarks/bench_cli_help.py, not here."""

import subprocess
import sys

HEAVY = ("torch", "cv2", "trimesh", "matplotlib", "scipy", "skimage")

PROBE = """
import sys
from edofproj.cli import build_parser
parser = build_parser()
for command in [[]] + [line.split() for line in sys.argv[1:]]:
    try:
        parser.parse_args(command + ["--help"])
    except SystemExit:
        pass
print("heavy:" + ",".join(m for m in {heavy} if m in sys.modules))
"""


def command_lines(parser=None, prefix=()):
    """Every command and sub-command, e.g. ``"live"``, ``"procams calibrate"``."""
    import argparse

    from edofproj.cli import build_parser

    parser = parser or build_parser()
    lines = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                lines.append(" ".join(prefix + (name,)))
                lines += command_lines(sub, prefix + (name,))
    return lines


def test_help_of_every_command_loads_no_heavy_library():
    lines = command_lines()
    assert {"live", "compensate", "bench", "procams", "export", "procams calibrate"} <= set(lines)
    result = subprocess.run(
        [sys.executable, "-c", PROBE.format(heavy=HEAVY), *lines], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip().splitlines()[-1] == "heavy:"


def test_constants_kept_in_the_commands_match_the_libraries():
    """Constants that the parsers need are repeated there (importing them would load torch)."""
    from edofproj.application.live import DEFAULT_STALL_TIMEOUT_S
    from edofproj.commands import export, live
    from edofproj.compensation.export import EXPORT_FORMATS

    assert live.DEFAULT_STALL_TIMEOUT_S == DEFAULT_STALL_TIMEOUT_S
    assert export.EXPORT_FORMATS == EXPORT_FORMATS
