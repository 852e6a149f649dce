"""Fault cases: hostile but fair inputs and interruptions, run through the CLI; prints one table row each.

    PYTHONPATH=src python benchmarks/fault_cases.py [--only 1,4,...] [--keep DIR]

Each case runs ``python -m edofproj.cli ...`` in a subprocess (under a 4 GiB address-space limit,
so that a case that would allocate without bound fails fast instead of exhausting the machine)
and reports the exit codes and the last line the command wrote to stderr, plus what the case
checks afterwards (files left behind, what a run directory holds). Point ``PYTHONPATH`` at another
source tree to compare versions. Tiny configurations (``tests/tiny_configs.py``) keep it to a few
minutes on one CPU core.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from tiny_configs import TINY_EVALUATION, TINY_TRAINING  # noqa: E402

ADDRESS_SPACE_LIMIT = 4 * 2**30


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_LIMIT, ADDRESS_SPACE_LIMIT))


def sets(overrides) -> list[str]:
    return [a for o in overrides for a in ("--set", o)]


def start(args, cwd: Path, env_extra=None) -> subprocess.Popen:
    env = dict(os.environ, OMP_NUM_THREADS="1", EDOFPROJ_DEBUG="")
    env.update(env_extra or {})
    return subprocess.Popen(
        [sys.executable, "-m", "edofproj.cli", *map(str, args)],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_limit_memory,
    )


def cli(args, cwd: Path, env_extra=None) -> tuple[int, str]:
    """Exit code and the last non-empty stderr line (or stdout's, when stderr is empty)."""
    proc = start(args, cwd, env_extra)
    out, err = proc.communicate()
    return proc.returncode, last_line(err) or last_line(out)


def last_line(text: str) -> str:
    lines = [line.strip() for line in text.replace("\r", "\n").splitlines() if line.strip()]
    lines = [line for line in lines if "step/s" not in line and "it/s" not in line and "%|" not in line]
    return lines[-1][:220] if lines else ""


def warnings_of(text: str) -> list[str]:
    return [line.strip()[:200] for line in text.splitlines() if "warning:" in line]


class Cases:
    def __init__(self, work: Path):
        self.work = work
        self.rows: list[tuple[str, str, str]] = []

    def row(self, case: str, what: str, outcome: str) -> None:
        self.rows.append((case, what, outcome))
        print(f"| {case} | {what} | {outcome} |", flush=True)

    # -- shared inputs ----------------------------------------------------------
    def trained_run(self) -> Path:
        run = self.work / "run"
        if not run.is_dir():
            code, line = cli(["train", "--out", run, "--quiet", *sets(TINY_EVALUATION)], self.work)
            if code:
                raise SystemExit(f"cannot train the shared run: {line}")
        return run

    def psf_file(self) -> Path:
        path = self.work / "psf.npz"
        if not path.is_file():
            code, line = cli(
                ["psf", "--doe", "lens", "--depth-mm", "450,550", "--out", path, *sets(TINY_EVALUATION)], self.work
            )
            if code:
                raise SystemExit(f"cannot simulate the shared PSF: {line}")
        return path

    def image(self) -> Path:
        path = self.work / "image.png"
        if not path.is_file():
            import cv2

            cv2.imwrite(str(path), (np.random.default_rng(0).random((48, 64, 3)) * 255).astype(np.uint8))
        return path

    def edited_npz(self, source: Path, target: Path, **changes) -> Path:
        data = dict(np.load(source, allow_pickle=False))
        for key, value in changes.items():
            if value is None:
                data.pop(key, None)
            else:
                data[key] = value(data[key]) if callable(value) else value
        with open(target, "wb") as handle:
            np.savez(handle, **data)
        return target

    # -- the cases ----------------------------------------------------------------
    def case_1(self) -> None:
        out = self.work / "collide"
        shutil.rmtree(out, ignore_errors=True)
        args = [
            "train",
            "--out",
            out,
            "--quiet",
            *sets(TINY_TRAINING + ["train.steps=40", "train.checkpoint_every=10"]),
        ]
        first = start(args, self.work)
        time.sleep(0.5)
        second = start(args, self.work)
        (_, err1), (_, err2) = first.communicate(), second.communicate()
        refused = err2 if second.returncode else err1
        self.row(
            "1",
            "two `train` on one `--out` at once",
            f"exit {first.returncode} and {second.returncode}; {last_line(refused) or 'no message'}",
        )

    def case_2(self) -> None:
        psf = self.psf_file()
        zero = self.edited_npz(psf, self.work / "zero_psf.npz", psf=lambda p: np.zeros_like(p))
        negative = self.edited_npz(psf, self.work / "negative_psf.npz", psf=lambda p: -p)
        for name, path in (("all-zero", zero), ("negative", negative)):
            code, line = cli(
                ["render", "--image", self.image(), "--psf", path, "--depth-index", 0, "--out", self.work / "r.png"],
                self.work,
            )
            self.row("2", f"{name} PSF file into `render`", f"exit {code}: {line or 'wrote an image'}")
        run = self.trained_run()
        code, line = cli(["finetune", run, "--psfs", zero, "--steps", 1, "--out", self.work / "ft_zero"], self.work)
        self.row("2", "all-zero PSF file into `finetune`", f"exit {code}: {line}")

    def design(self) -> Path:
        return self.trained_run() / "doe.npz"

    def case_3(self) -> None:
        bad = self.edited_npz(
            self.design(),
            self.work / "mismatch.npz",
            height_m=lambda h: h[:10],
            level=lambda v: v[:10],
            ring_edges_m=lambda e: np.linspace(0, e[-1], 129),
        )
        code, line = cli(["psf", "--doe", bad, "--depth-mm", 500, "--out", self.work / "p3.npz"], self.work)
        self.row("3", "design with 10 heights, 129 ring edges: `psf`", f"exit {code}: {line}")
        code, line = cli(["export-doe", bad, "--out", self.work / "fab3"], self.work)
        self.row("3", "the same design: `export-doe`", f"exit {code}: {line}")

    def case_4(self) -> None:
        code, line = cli(
            ["psf", "--doe", "lens", "--depth-mm", 500, "--set", "psf.window=100001", "--out", self.work / "p4.npz"],
            self.work,
        )
        self.row("4", "`psf --set psf.window=100001` (4 GiB address-space limit)", f"exit {code}: {line}")

    def case_5(self) -> None:
        bad = self.edited_npz(self.design(), self.work / "noheight.npz", height_m=None)
        code, line = cli(["psf", "--doe", bad, "--depth-mm", 500, "--out", self.work / "p5.npz"], self.work)
        self.row("5", "design without `height_m`: `psf`", f"exit {code}: {line}")
        code, line = cli(["export-doe", bad, "--out", self.work / "fab5"], self.work)
        self.row("5", "design without `height_m`: `export-doe`", f"exit {code}: {line}")

    def case_6(self) -> None:
        code, line = cli(
            ["procams", "patterns", "--width", 100000, "--height", 100000, "--out", self.work / "pat6"], self.work
        )
        self.row("6", "`procams patterns --width 100000 --height 100000`", f"exit {code}: {line}")

    def case_7(self) -> None:
        import cv2

        path = self.work / "huge.png"
        if not path.is_file():
            cv2.imwrite(str(path), np.zeros((20000, 20000), np.uint8))
        code, line = cli(
            ["render", "--image", path, "--psf", self.psf_file(), "--depth-index", 0, "--out", self.work / "r7.png"],
            self.work,
        )
        self.row("7", "20000x20000 PNG into `render` (4 GiB address-space limit)", f"exit {code}: {line}")

    def case_8(self) -> None:
        run = self.work / "interrupted"
        base = TINY_TRAINING + ["train.steps=4", "train.checkpoint_every=2", "train.batch_size=1"]
        code, line = cli(["train", "--out", run, "--quiet", *sets(base)], self.work)
        checkpoints = run / "checkpoints"
        last = checkpoints / "last.pt"
        data = last.read_bytes()
        (checkpoints / ".last.pt.k3j4h5g6.pt").write_bytes(data[: len(data) // 2])  # what kill -9 leaves
        last.write_bytes(data[: len(data) // 3])  # and a damaged last.pt
        proc = start(["train", "--out", run, "--resume", "--steps", 6, "--quiet"], self.work)
        out, err = proc.communicate()
        left = sorted(p.name for p in checkpoints.glob(".*"))
        said = "; ".join(w.split("warning: ", 1)[1][:90] for w in warnings_of(err)) or "nothing said"
        self.row(
            "8",
            "partial temp checkpoint + truncated `last.pt`, then `--resume`",
            f"exit {proc.returncode}: {last_line(err) or last_line(out)}; temp files left: {left or 'none'}; {said}",
        )

    def case_9(self) -> None:
        run = self.trained_run()
        garbage = self.work / "garbage_run"
        if garbage.exists():
            shutil.rmtree(garbage)
        shutil.copytree(run, garbage)
        (garbage / "checkpoints" / "last.pt").write_bytes(os.urandom(3000))
        for p in (garbage / "checkpoints").glob("step_*.pt"):
            p.unlink()
        code, line = cli(["evaluate", garbage, "--quiet", "--methods", "doe+net"], self.work)
        self.row("9a", "garbage `last.pt`: `evaluate`", f"exit {code}: {line}")

        text = self.work / "text.npz"
        text.write_text("this is not an archive\n")
        code, line = cli(["render", "--image", self.image(), "--psf", text, "--out", self.work / "r9.png"], self.work)
        self.row("9b", "a text file given as `--psf x.npz`", f"exit {code}: {line}")

        mismatch = self.work / "net_mismatch"
        if mismatch.exists():
            shutil.rmtree(mismatch)
        shutil.copytree(run, mismatch)
        config = (mismatch / "config.yaml").read_text()
        (mismatch / "config.yaml").write_text(config.replace("- 4\n  - 8\n", "- 8\n  - 16\n", 1))
        code, line = cli(["evaluate", mismatch, "--quiet", "--methods", "doe+net"], self.work)
        self.row("9c", "network config not matching its checkpoint: `evaluate`", f"exit {code}: {line}")

        existing = self.work / "ft_existing"
        existing.mkdir(exist_ok=True)
        (existing / "notes.txt").write_text("x")
        code, line = cli(["finetune", run, "--psfs", self.psf_file(), "--steps", 1, "--out", existing], self.work)
        self.row("9d", "`finetune --out` a non-empty directory", f"exit {code}: {line}")

        code, line = cli(["psf", "--doe", "lens", "--depth-mm", 500, "--out", "/sys/psf.npz"], self.work)
        self.row("9e", "`psf --out` in a directory that refuses writes (/sys)", f"exit {code}: {line}")

        code, line = cli(["train", "--out", self.work / "empty_set", "--set", "train.steps="], self.work)
        self.row("9f", "`--set train.steps=`", f"exit {code}: {line}")

        images = self.work / "images9"
        images.mkdir(exist_ok=True)
        shutil.copy(self.image(), images / "good.png")
        (images / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(100))
        out = self.work / "eval9"
        code, line = cli(
            ["evaluate", run, "--images", images, "--out", out, "--quiet", "--methods", "doe,doe+net"], self.work
        )
        report = (out / "report.md").read_text() if (out / "report.md").is_file() else ""
        named = "named" if "broken.png" in report else "NOT named"
        self.row("9g", "`evaluate --images` with one unreadable image", f"exit {code}; the report: {named}")

    def case_10(self) -> None:
        run = self.trained_run()
        first = start(
            ["evaluate", run, "--quiet", "--methods", "doe,doe+net", "--out", self.work / "eval10"], self.work
        )
        time.sleep(1.0)
        code, line = cli(["evaluate", run, "--quiet", "--methods", "doe", "--out", self.work / "eval10"], self.work)
        first.communicate()
        self.row("10", "two `evaluate` writing one `--out` at once", f"exit {first.returncode} and {code}: {line}")

    def case_11(self) -> None:
        import signal

        run = self.work / "killed"
        shutil.rmtree(run, ignore_errors=True)
        args = [
            "train",
            "--out",
            run,
            "--quiet",
            *sets(TINY_TRAINING + ["train.steps=200", "train.checkpoint_every=2"]),
        ]
        proc = start(args, self.work)
        deadline = time.time() + 120
        while time.time() < deadline and not (run / "checkpoints" / "last.pt").is_file():
            time.sleep(0.2)
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate()
        lock_left = (run / ".edofproj.lock").exists()
        code_proc = start(["train", "--out", run, "--resume", "--stop-after", 4, "--quiet"], self.work)
        _, err = code_proc.communicate()
        said = "; ".join(w.split("warning: ", 1)[1][:110] for w in warnings_of(err)) or "nothing said"
        self.row(
            "11",
            "`kill -9` during training, then `--resume` (lock file of the dead process)",
            f"lock file left by the kill: {'yes' if lock_left else 'no'}; resume exit {code_proc.returncode}; {said}",
        )

    def case_12(self) -> None:
        psf = self.psf_file()
        truncated = self.work / "truncated_psf.npz"
        data = psf.read_bytes()
        truncated.write_bytes(data[: len(data) // 2])
        code, line = cli(
            ["render", "--image", self.image(), "--psf", truncated, "--out", self.work / "r12.png"], self.work
        )
        self.row("12", "truncated PSF file into `render`", f"exit {code}: {line}")
        design = self.work / "truncated_doe.npz"
        data = self.design().read_bytes()
        design.write_bytes(data[: len(data) // 2])
        code, line = cli(["psf", "--doe", design, "--depth-mm", 500, "--out", self.work / "p12.npz"], self.work)
        self.row("12", "truncated design file into `psf`", f"exit {code}: {line}")
        even = self.edited_npz(psf, self.work / "even_psf.npz", psf=lambda p: p[..., :-1, :-1])
        code, line = cli(
            ["render", "--image", self.image(), "--psf", even, "--depth-index", 0, "--out", self.work / "r.png"],
            self.work,
        )
        self.row("12", "PSF file with an even (14x14) window", f"exit {code}: {line}")
        bright = self.edited_npz(psf, self.work / "bright_psf.npz", psf=lambda p: 3 * p)
        code, line = cli(
            ["render", "--image", self.image(), "--psf", bright, "--depth-index", 0, "--out", self.work / "r.png"],
            self.work,
        )
        self.row("12", "PSF file with 3x the pupil's energy", f"exit {code}: {line}")
        lost = self.edited_npz(psf, self.work / "depths_psf.npz", depths_m=lambda d: d[:1])
        code, line = cli(
            ["render", "--image", self.image(), "--psf", lost, "--depth-index", 0, "--out", self.work / "r.png"],
            self.work,
        )
        self.row("12", "PSF file with 2 PSFs and 1 depth", f"exit {code}: {line}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="", help="comma-separated case numbers (default: all)")
    parser.add_argument("--keep", default=None, help="work in this directory and keep it")
    args = parser.parse_args()
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="edofproj-faults-"))
    work.mkdir(parents=True, exist_ok=True)
    cases = Cases(work)
    chosen = [c for c in args.only.split(",") if c] or [str(i) for i in range(1, 13)]
    print("| case | what | outcome |\n| --- | --- | --- |")
    clock = time.perf_counter()
    for number in chosen:
        getattr(cases, f"case_{number}")()
    print(f"\n{len(cases.rows)} outcomes in {time.perf_counter() - clock:.0f} s ({work})")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
