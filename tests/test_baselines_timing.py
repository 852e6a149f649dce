"""Timing utilities and the ``edofproj bench`` command (tiny frames: this checks plumbing, not speed)."""

import csv
import time

import pytest
import torch

from edofproj.cli import main
from edofproj.errors import EdofprojError
from edofproj.evaluation.timing import Case, Timing, format_table, measure_ms, parse_sizes, time_cases, timings_csv


def test_measure_ms_runs_warmup_then_times_each_repeat():
    calls = []

    def frame():
        calls.append(time.perf_counter())
        time.sleep(0.002)

    times = measure_ms(frame, repeats=4, warmup=2)
    assert len(calls) == 6 and len(times) == 4
    assert min(times) >= 2.0  # each timed call sleeps 2 ms


def test_a_time_budget_stops_the_repeats_once_the_timed_frames_add_up_to_it(monkeypatch):
    # a fake clock: each frame advances it by its length, so the test does not depend on the machine's speed
    clock = [0.0]
    monkeypatch.setattr("edofproj.evaluation.timing.time.perf_counter", lambda: clock[0])
    lengths = iter([4.0, 2.0, 2.0, 2.0, 2.0, 2.0])  # seconds: one warm-up frame, then the timed ones

    def frame():
        clock[0] += next(lengths)

    times = measure_ms(frame, repeats=5, warmup=1, budget_s=5.0)
    assert times == [2000.0, 2000.0, 2000.0]  # 6 s >= 5 s after the third timed frame; the warm-up is not counted
    one = iter([7.0])
    results = time_cases(
        [Case("m", "b", "cpu", lambda h, w: lambda: clock.__setitem__(0, clock[0] + next(one)))],
        [(4, 4)],
        repeats=3,
        warmup=0,
        budget_s=5.0,
    )
    assert results[0].repeats == 1 and results[0].median_ms == 7000.0


def test_time_cases_builds_one_frame_function_per_size():
    built = []

    def build(height, width):
        built.append((height, width))
        return lambda: None

    results = time_cases([Case("m", "b", "cpu", build)], [(4, 5), (6, 7)], repeats=2, warmup=0)
    assert built == [(4, 5), (6, 7)]
    assert [(t.height, t.width, t.repeats) for t in results] == [(4, 5, 2), (6, 7, 2)]


def test_sizes_table_and_csv():
    assert parse_sizes("256x256, 600X800") == [(256, 256), (600, 800)]
    for bad in ("600", "axb", "0x5", ""):
        with pytest.raises(EdofprojError):
            parse_sizes(bad)
    timings = [
        Timing("wiener", "scipy", "cpu", 8, 8, 1.25, 3),
        Timing("unet", "torch", "cpu", 8, 8, 10.0, 3),
        Timing("wiener", "scipy", "cpu", 16, 8, 2.5, 3),
    ]
    table = format_table(timings).splitlines()
    assert table[0] == "| method | backend | device | 8x8 (ms) | 16x8 (ms) |"
    assert table[2] == "| wiener | scipy | cpu | 1.25 | 2.50 |"  # two decimals below 10 ms
    assert table[3] == "| unet | torch | cpu | 10.0 | n/a |"
    rows = list(csv.DictReader(timings_csv(timings).splitlines()))
    assert [(r["method"], r["height"], float(r["median_ms"])) for r in rows] == [
        ("wiener", "8", 1.25),
        ("unet", "8", 10.0),
        ("wiener", "16", 2.5),
    ]


@pytest.fixture
def restore_threads():
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def test_bench_cli_times_every_method_and_backend(tmp_path, capsys, restore_threads):
    out = tmp_path / "bench.csv"
    code = main(
        [
            "bench",
            "--sizes",
            "24x40",
            "--repeats",
            "1",
            "--warmup",
            "0",
            "--widths",
            "4,8",
            "--methods",
            "wiener,unet,onlineprodeb,cls",
            "--cls-iterations",
            "2",
            "--window",
            "5",
            "--device",
            "cpu",
            "--threads",
            "1",
            "--csv",
            str(out),
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "| method | backend | device | 24x40 (ms) |" in printed
    rows = list(csv.DictReader(out.read_text().splitlines()))
    assert {(r["method"], r["backend"]) for r in rows} == {
        ("wiener", "scipy"),
        ("wiener", "torch"),
        ("unet", "torch"),
        ("unet", "onnxruntime"),
        ("onlineprodeb", "torch"),
        ("onlineprodeb", "onnxruntime"),
        ("cls", "torch"),
    }
    assert all(float(r["median_ms"]) > 0 for r in rows)


def test_bench_cli_times_the_multirate_network(capsys, restore_threads):
    """An untrained multi-rate network runs on contiguous frames (it reads them with strided
    convolutions); its ONNX export holds the Fourier filter for one frame size, so each size gets
    its own export."""
    pytest.importorskip("onnxscript")
    code = main(
        [
            "bench",
            "--sizes",
            "24x40,20x28",
            "--repeats",
            "1",
            "--warmup",
            "0",
            "--methods",
            "unet",
            "--architecture",
            "multirate",
            "--widths",
            "4,8",
            "--space-to-depth",
            "4",
            "--prefilter-bins",
            "8",
            "--device",
            "cpu",
            "--threads",
            "1",
        ]
    )
    assert code == 0
    captured = capsys.readouterr()
    assert "| multirate | torch | cpu |" in captured.out
    assert "| multirate | onnxruntime | cpu |" in captured.out
    assert "multirate/onnxruntime/cpu 20x28" in captured.err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--sizes", "256"], "HEIGHTxWIDTH"),
        (["--methods", "wiener,magic"], "unknown method 'magic'"),
        (["--widths", "huge"], "unknown U-Net width preset"),
        (["--run", "somewhere", "--widths", "fast"], "exclude each other"),
        (["--window", "4", "--methods", "wiener"], "odd"),
        (["--architecture", "multirate", "--prefilter-bins", "48"], "--space-to-depth >= 2"),
    ],
)
def test_bench_cli_errors_are_one_line(argv, message, capsys):
    assert main(["bench", "--repeats", "1", "--warmup", "0", "--sizes", "16x16", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err


def test_bench_cli_a_failing_compiler_is_one_line(monkeypatch, capsys, restore_threads):
    """torch.compile compiles at the first call of each size; a compiler that fails there (no C++
    compiler on a CPU, an unsupported operator) ends the command in one line naming --compile."""

    def failing_compile(module, **options):
        def compiled(*args):
            raise RuntimeError("InductorError: no working C++ compiler found\n(many more lines)")

        return compiled

    monkeypatch.setattr(torch, "compile", failing_compile)
    argv = ["bench", "--sizes", "16x16", "--repeats", "1", "--warmup", "0", "--methods", "unet", "--no-onnx"]
    assert main(argv + ["--widths", "4,8", "--device", "cpu", "--threads", "1", "--compile"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("edofproj: error: torch.compile of unet failed at 16x16 (InductorError: no working C++")
    assert err[-1].endswith("leave out --compile")
