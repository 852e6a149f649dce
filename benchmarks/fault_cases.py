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

    # -- issue 60 (round four), the procams lab path: items 3, 4, 6, 8, 9, 10, 12 ------------------
    # Inputs are written with NumPy and OpenCV only, so that the same case runs against any source tree.
    def _lab_dir(self, name: str) -> Path:
        folder = self.work / name
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        return folder

    @staticmethod
    def _write_grey(path: Path, image) -> None:
        import cv2

        cv2.imwrite(str(path), np.rint(np.clip(image, 0, 1) * 255).astype(np.uint8))

    @staticmethod
    def _lab_json(folder: Path, sequences, hw=(48, 64), name="lab.json", **top) -> Path:
        import json

        data = {"format": "edofproj-lab-captures", "version": 1, "projector": {"height": hw[0], "width": hw[1]},
                "sequences": sequences} | top  # fmt: skip
        (folder / name).write_text(json.dumps(data), encoding="utf-8")
        return folder / name

    @staticmethod
    def _gray_planes(length: int) -> np.ndarray:
        n = int(np.ceil(np.log2(length)))
        c = np.arange(length)
        g = c ^ (c >> 1)
        return np.stack([(g >> (n - 1 - b)) & 1 for b in range(n)]).astype(float)  # (n, L)

    @staticmethod
    def _phase_frames(length: int, periods, steps: int) -> np.ndarray:
        c = np.arange(length)
        return np.stack([0.5 + 0.5 * np.cos(2 * np.pi * f * c / length + 2 * np.pi * k / steps)
                         for f in periods for k in range(steps)])  # fmt: skip

    def _frames(self, folder: Path, prefix: str, frames) -> list[str]:
        names = []
        for i, frame in enumerate(frames):
            names.append(f"{prefix}_{i:02d}.png")
            self._write_grey(folder / names[-1], frame)
        return names

    def _ideal_lab(self, folder: Path, hw=(48, 64)) -> Path:
        """Phase shifts along x and y, an identity camera, captures between 0.1 and 0.9."""
        H, W = hw
        sequences = []
        for axis, length, periods in (("x", W, [1, 4, 16]), ("y", H, [1, 4, 12])):
            profiles = self._phase_frames(length, periods, 4)
            images = [np.broadcast_to(p[None, :] if axis == "x" else p[:, None], hw) for p in profiles]
            names = self._frames(folder, f"phase_{axis}", [0.1 + 0.8 * im for im in images])
            sequences.append({"name": f"phase_{axis}", "kind": "phase-shift", "axis": axis, "periods": periods,
                              "steps": 4, "files": {"list": names}})  # fmt: skip
        for name, level in (("black", 0.1), ("white", 0.9)):
            self._write_grey(folder / f"{name}.png", np.full(hw, level))
        return self._lab_json(folder, sequences, hw)

    @staticmethod
    def _valid_share(path: Path, columns=None) -> str:
        if not path.is_file():
            return "no map written"
        proj_x = np.load(path)["proj_x"]
        valid = np.isfinite(proj_x) if columns is None else np.isfinite(proj_x[:, columns])
        return f"{valid.mean():.1%} valid"

    def case_lab3(self) -> None:
        folder = self._lab_dir("lab3")
        planes = self._gray_planes(256)  # (8, 256)
        unlit, frames = 144, []
        rng = np.random.default_rng(0)
        offsets = np.random.default_rng(7).uniform(0.0, 0.25, len(planes))
        for i, p in enumerate(planes):  # 36 % of the camera unlit; gain and dark level vary on the projection only
            frame = np.full((32, unlit + 256), 0.06)
            frame[:, unlit:] = 0.06 + offsets[i] + (0.8 + 0.3 * i / len(planes)) * 0.6 * p[None, :]
            frames.append(frame + 0.004 * rng.standard_normal(frame.shape))
        names = self._frames(folder, "gray", frames)
        lab = self._lab_json(folder, [{"name": "gray", "kind": "gray-code", "axis": "x", "files": {"list": names}}],
                             hw=(32, 256))  # fmt: skip
        code, line = cli(["procams", "decode", "--lab", lab, "--x", "gray", "--out", folder / "map.npz"], self.work)
        columns = ""
        if (folder / "map.npz").is_file():
            seen = np.load(folder / "map.npz")["proj_x"][:, :unlit]
            columns = f" (decoded to columns {np.unique(seen[np.isfinite(seen)])[:3].tolist()})"
        self.row("60.3", "`decode` of a Gray code with 36 % of the camera unlit",
                 f"exit {code}; unlit part {self._valid_share(folder / 'map.npz', slice(0, unlit))}{columns}; {line}")  # fmt: skip
        for kind in ("gray-code", "phase-shift"):
            noise = self._lab_dir(f"lab3_{kind}")
            count = 8 if kind == "gray-code" else 12
            names = self._frames(noise, "noise", rng.uniform(0.05, 0.95, (count, 64, 256)))
            seq = {"name": "s", "kind": kind, "axis": "x", "files": {"list": names}}
            seq |= {"planes": 8} if kind == "gray-code" else {"periods": [1, 4, 16], "steps": 4}
            lab = self._lab_json(noise, [seq], hw=(32, 256))
            code, line = cli(["procams", "decode", "--lab", lab, "--x", "s", "--out", noise / "map.npz"], self.work)
            self.row("60.3", f"`decode` of pure-noise {kind} captures",
                     f"exit {code}; {self._valid_share(noise / 'map.npz')}; {line}")  # fmt: skip

    def case_lab4(self) -> None:
        folder = self._lab_dir("lab4")
        lab = self._ideal_lab(folder)
        for what, axes in (("`decode --x phase_y` (declared axis y)", ["--x", "phase_y"]),
                           ("`decode --x phase_y --y phase_x` (swapped)", ["--x", "phase_y", "--y", "phase_x"])):  # fmt: skip
            out = folder / "map.npz"
            out.unlink(missing_ok=True)
            code, line = cli(["procams", "decode", "--lab", lab, *axes, "--out", out], self.work)
            self.row("60.4", what, f"exit {code}; {line}")

    def case_lab6(self) -> None:
        folder = self._lab_dir("lab6")
        for name in ("a.png", "b.png"):
            self._write_grey(folder / name, np.zeros((4, 4)))
        gray = {"name": "g", "kind": "gray-code", "axis": "x", "planes": 2, "files": {"list": ["a.png", "b.png"]}}
        outside = self._lab_dir("lab6_elsewhere")
        self._write_grey(outside / "secret.png", np.zeros((4, 4)))
        (folder / "link.png").symlink_to(outside / "secret.png")
        for what, seq, top in (
            ("lab manifest: the same file twice in one sequence", gray | {"files": {"list": ["a.png", "a.png"]}}, {}),
            ('lab manifest: `"planes": 7.5`', gray | {"planes": 7.5}, {}),
            ('lab manifest: `"version": 2`', gray, {"version": 2}),
            ("lab manifest: a link in the folder to a file outside it", gray | {"files": {"list": ["a.png", "link.png"]}}, {}),
        ):  # fmt: skip
            lab = self._lab_json(folder, [seq], **top)
            code, line = cli(["procams", "decode", "--lab", lab, "--x", "g", "--out", folder / "m.npz"], self.work)
            self.row("60.6", what, f"exit {code}; {line}")

    def case_lab8(self) -> None:
        for level, what in ((0.0, "all-black"), (1.0, "all-white")):
            folder = self._lab_dir(f"lab8_{what}")
            names = self._frames(folder, "flat", np.full((6, 48, 64), level))
            lab = self._lab_json(folder, [{"name": "g", "kind": "gray-code", "axis": "x", "files": {"list": names}}])
            code, line = cli(["procams", "decode", "--lab", lab, "--x", "g", "--out", folder / "map.npz"], self.work)
            self.row("60.8", f"`decode` of {what} Gray-code captures",
                     f"exit {code}; {self._valid_share(folder / 'map.npz')}; {line}")  # fmt: skip
        folder = self._lab_dir("lab8")
        lab = self._ideal_lab(folder)
        code, line = cli(["procams", "decode", "--lab", lab, "--x", "phase_x", "--y", "phase_y", "--out",
                          folder / "map.npz"], self.work)  # fmt: skip
        predict = ["procams", "predict", "--map", folder / "map.npz", "--image", folder / "phase_x_08.png",
                   "--capture", folder / "phase_x_08.png", "--black", folder / "black.png", "--white", folder / "white.png"]  # fmt: skip
        code, line = cli([*predict, "--offset-px", "1e30", "0"], self.work)
        self.row("60.8", "`predict --offset-px 1e30 0`", f"exit {code}; {line}")
        out = folder / "map2.npz"
        code, line = cli(["procams", "decode", "--lab", lab, "--x", "phase_x", "--planes", 2, "--out", out], self.work)
        self.row("60.8", "`decode --planes 2` on a phase-shift sequence", f"exit {code}; {line}")
        code, line = cli([*predict, "--offset-px", "nan", "0"], self.work)
        self.row("60.12", "`predict --offset-px nan 0`", f"exit {code}; {line}")
        swapped = [*predict[:-4], "--black", folder / "white.png", "--white", folder / "black.png"]
        code, line = cli(swapped, self.work)
        self.row("60.12", "`predict` with `--black` and `--white` swapped", f"exit {code}; {line}")
        code, line = cli(["procams", "decode", "--lab", lab, "--x", "phase_x", "--y", "phase_x", "--out",
                          folder / "map3.npz"], self.work)  # fmt: skip
        self.row("60.12", "`decode --x phase_x --y phase_x`", f"exit {code}; {line}")

    def case_lab9(self) -> None:
        folder = self._lab_dir("lab9")
        lab = self._ideal_lab(folder)
        cli(["procams", "decode", "--lab", lab, "--x", "phase_x", "--y", "phase_y", "--out", folder / "map.npz"],
            self.work)  # fmt: skip
        dots = np.zeros((48, 64))
        dots[::8, ::8] = 1.0
        self._write_grey(folder / "dots.png", 0.1 + 0.8 * dots)
        import json

        data = json.loads(lab.read_text())
        data["sequences"].append({"name": "dots", "kind": "dots", "spacing_px": [8, 8], "origin_px": [60, 0],
                                  "files": {"list": ["dots.png"]}})  # fmt: skip
        lab.write_text(json.dumps(data))
        code, line = cli(["procams", "psf-map", "--lab", lab, "--dots", "dots", "--map", folder / "map.npz",
                          "--out", folder / "psf.npz"], self.work)  # fmt: skip
        self.row("60.9", "`psf-map` with a dots `origin_px` [60, 0] below a 48-row projector", f"exit {code}; {line}")

    def case_lab10(self) -> None:
        folder = self._lab_dir("lab10")
        (folder / "lab.json").write_text("[" * 100000 + "]" * 100000)
        code, line = cli(["procams", "decode", "--lab", folder / "lab.json", "--x", "g", "--out", folder / "m.npz"],
                         self.work)  # fmt: skip
        self.row("60.10", "a lab.json nested 100000 deep", f"exit {code}; {line}")

    def case_lab12(self) -> None:
        folder = self._lab_dir("lab12")
        (folder / "dir.json").mkdir()
        os.mkfifo(folder / "fifo.json")
        for what, lab in (("a lab file that is a folder", folder / "dir.json"),
                          ("a lab file that is a FIFO", folder / "fifo.json"),
                          ("a lab file that is a device (`/dev/zero`)", Path("/dev/zero"))):  # fmt: skip
            proc = start(["procams", "decode", "--lab", lab, "--x", "g", "--out", folder / "m.npz"], self.work)
            try:
                _, err = proc.communicate(timeout=60)
                outcome = f"exit {proc.returncode}; {last_line(err)}"
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
                outcome = "still reading after 60 s (killed)"
            self.row("60.12", what, outcome)
        for name in ("a.png", "b.png", "c.png", "d.png"):
            self._write_grey(folder / name, np.zeros((4, 4)))
        lab = folder / "nan.json"
        lab.write_text('{"format": "edofproj-lab-captures", "version": 1, "projector": {"height": 40, "width": 48}, '
                       '"sequences": [{"name": "p", "kind": "phase-shift", "axis": "x", "periods": [1, NaN], '
                       '"steps": 2, "files": {"list": ["a.png", "b.png", "c.png", "d.png"]}}]}')  # fmt: skip
        code, line = cli(["procams", "decode", "--lab", lab, "--x", "p", "--out", folder / "m.npz"], self.work)
        self.row("60.12", "a lab manifest with a NaN period", f"exit {code}; {line}")

    # -- issue 60 (round four), outside the procams steps: items 1, 2, 5, 7, 8, 11, 12 -------------------
    def case_r4_1(self) -> None:
        import json

        folder = self._lab_dir("r4_1")
        lab = self._ideal_lab(folder)
        cli(["procams", "decode", "--lab", lab, "--x", "phase_x", "--y", "phase_y", "--out", folder / "map.npz"],
            self.work)  # fmt: skip
        yy, xx = np.mgrid[0:48, 0:64]
        dots = sum(np.exp(-((yy - y) ** 2 + (xx - x) ** 2) / 2.0) for y in range(4, 48, 8) for x in range(4, 64, 8))
        self._write_grey(folder / "dots.png", 0.1 + 0.8 * dots)
        data = json.loads(lab.read_text())
        data["sequences"].append({"name": "dots", "kind": "dots", "spacing_px": [8, 8], "origin_px": [4, 4],
                                  "files": {"list": ["dots.png"]}})  # fmt: skip
        lab.write_text(json.dumps(data))
        before = (folder / "dots.png").read_bytes()
        code, line = cli(["procams", "psf-map", "--lab", lab, "--dots", "dots", "--map", folder / "map.npz",
                          "--out", folder / "psf.npz", "--figure", folder / "dots.png"], self.work)  # fmt: skip
        kept = "capture kept" if (folder / "dots.png").read_bytes() == before else "THE CAPTURE WAS REPLACED"
        self.row("60.1", "`psf-map --figure` named like the dot capture it reads", f"exit {code}; {kept}; {line}")

    def _run_copy(self, name: str) -> Path:
        import subprocess as sp

        run = self.work / name
        shutil.rmtree(run, ignore_errors=True)
        source = sp.run([sys.executable, "-c", "from edofproj.builtin_runs import builtin_run_dir as b; "
                         "print(b('cpu-doe-net'))"], capture_output=True, text=True).stdout.strip()  # fmt: skip
        shutil.copytree(source, run)
        return run

    def case_r4_2(self) -> None:
        run = self._run_copy("r4_2_run")
        last = run / "checkpoints" / "last.pt"
        before = last.read_bytes()
        code, line = cli(["export", run, "--format", "torchscript", "--height", 64, "--width", 64, "--out", last],
                         self.work)  # fmt: skip
        kept = "checkpoint kept" if last.read_bytes() == before else "THE CHECKPOINT WAS REPLACED"
        self.row("60.2", "`export RUN --out RUN/checkpoints/last.pt`", f"exit {code}; {kept}; {line}")

    def case_r4_5(self) -> None:
        folder = self._lab_dir("r4_5")
        header = "method,depth_mm,image,psnr,ssim,ms_ssim\n"
        for seed in (0, 1):
            rows = "".join(f"{m},{z},a.png,30,0.8{seed},0.9\n" for m in ("doe+net", "doe") for z in (300, 500))
            (folder / f"e{seed}").mkdir()
            (folder / f"e{seed}" / "metrics.csv").write_text(header + rows + "doe+net,300,a.png,30,0,0.9\n" * seed)
        proc = start(["summarize", folder / "e0", folder / "e1"], self.work)
        out, err = proc.communicate()
        said = last_line(err) or next((r for r in out.splitlines() if r.startswith("| doe+net")), "")
        self.row("60.5", "`summarize` of a metrics.csv with one (method, depth, image) row twice (SSIM 0)",
                 f"exit {proc.returncode}; {said}")  # fmt: skip

    def case_r4_7(self) -> None:
        import signal

        folder = self._lab_dir("r4_7")
        out = folder / "net.pt"
        args = ["export", "builtin:cpu-doe-net", "--format", "torchscript", "--height", 64, "--width", 64, "--out", out]
        proc = start(args, self.work)
        deadline = time.time() + 300  # the temporary file appears while the export writes
        while time.time() < deadline and proc.poll() is None and not list(folder.glob(".net.pt.tmp-*")):
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
        proc.communicate()
        left = sorted(p.name for p in folder.glob(".net.pt.tmp-*"))
        code, line = cli(args, self.work)
        after = sorted(p.name for p in folder.glob(".net.pt.tmp-*"))
        self.row("60.7", "`kill -9` during `export`, then `export` again into the same folder",
                 f"temporary files after the kill: {len(left)}; next export exit {code}, temporary files then: "
                 f"{len(after)}")  # fmt: skip

    def case_r4_8(self) -> None:
        proc = start(["tune-classic", "--element", "cubic", "--values", "", "--out", self.work / "r4_8"], self.work)
        try:
            _, err = proc.communicate(timeout=60)
            outcome = f"exit {proc.returncode}; {last_line(err)}"
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
            outcome = f"still sweeping after 60 s (killed): {last_line(err)}"
        self.row("60.8", '`tune-classic --element cubic --values ""`', outcome)

    def case_r4_11(self) -> None:
        import cv2

        path = self.work / "huge.png"
        if not path.is_file():
            cv2.imwrite(str(path), np.zeros((20000, 20000), np.uint8))
        code, line = cli(["compensate", "builtin:cpu-doe-net", "--image", path, "--depth-mm", 500, "--out",
                          self.work / "r4_11.png"], self.work)  # fmt: skip
        self.row(
            "60.11", "20000x20000 PNG into `compensate --image` (4 GiB address-space limit)", f"exit {code}; {line}"
        )
        small = self.work / "r4_11_1000.png"
        cv2.imwrite(str(small), np.zeros((1000, 1000, 3), np.uint8))
        code, line = cli(["compensate", "builtin:cpu-doe-net", "--image", small, "--depth-mm", 500, "--out",
                          self.work / "r4_11b.png"], self.work, {"EDOFPROJ_MEMORY_BYTES": "150e6"})  # fmt: skip
        self.row("60.11", "1000x1000 image into `compensate --image` with 150 MB available", f"exit {code}; {line}")

    def case_r4_12(self) -> None:
        import cv2

        image = self.image()
        folder = self.work / "r4_12_show"
        folder.mkdir(exist_ok=True)
        cv2.imwrite(str(folder / "big.png"), np.zeros((1400, 1400, 3), np.uint8))
        data = bytearray(cv2.imencode(".png", np.zeros((48, 64, 3), np.uint8))[1].tobytes())
        data[data.find(b"IDAT") + 10] ^= 0xFF
        (self.work / "damaged.png").write_bytes(bytes(data))
        out = self.work / "r4_12.png"
        for what, args, env in (
            ("`compensate --method multifocal+net` without its run",
             ["compensate", "builtin:cpu-doe-net", "--method", "multifocal+net", "--image", image, "--depth-mm", 500,
              "--out", out], None),
            ("`compensate --images` of a 1400x1400 image, `--batch 1`, 150 MB available",
             ["compensate", "builtin:cpu-doe-net", "--images", folder, "--batch", 1, "--depth-mm", 500, "--out",
              self.work / "r4_12_out"], {"EDOFPROJ_MEMORY_BYTES": "150e6"}),
            ("`tune-classic --element cubic --values 1e9`",
             ["tune-classic", "--element", "cubic", "--values", "1e9", "--out", self.work / "r4_12_t"], None),
            ("`compensate --depth-mm 1e-9`",
             ["compensate", "builtin:cpu-doe-net", "--image", image, "--depth-mm", "1e-9", "--out", out], None),
            ("a damaged PNG into `render` (all of stderr)",
             ["render", "--image", self.work / "damaged.png", "--doe", "lens", "--depth-mm", 500, "--out", out], None),
            ("`bench --sizes -5x10`", ["bench", "--sizes", "-5x10"], None),
            ("`evaluate --depths-mm 800:300:100`",
             ["evaluate", "builtin:cpu-doe-net", "--depths-mm", "800:300:100", "--out", self.work / "r4_12_ev"], None),
        ):  # fmt: skip
            proc = start(args, self.work, env)
            _, err = proc.communicate()
            lines = [line.strip() for line in err.splitlines() if line.strip() and "%|" not in line]
            said = " / ".join(lines) if "damaged" in what else last_line(err)
            self.row("60.12", what, f"exit {proc.returncode}; {said[:300]}")


LAB_PATH_CASES = ["lab3", "lab4", "lab6", "lab8", "lab9", "lab10", "lab12"]
"""Issue 60's cases on the procams lab path (``--only lab3,...``)."""
ROUND_FOUR_CASES = ["r4_1", "r4_2", "r4_5", "r4_7", "r4_8", "r4_11", "r4_12"]
"""Issue 60's cases outside the procams steps (``--only r4_1,...``)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="", help="comma-separated case numbers (default: all)")
    parser.add_argument("--keep", default=None, help="work in this directory and keep it")
    args = parser.parse_args()
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="edofproj-faults-"))
    work.mkdir(parents=True, exist_ok=True)
    cases = Cases(work)
    chosen = [c for c in args.only.split(",") if c] or [
        str(i) for i in range(1, 13)
    ] + LAB_PATH_CASES + ROUND_FOUR_CASES
    print("| case | what | outcome |\n| --- | --- | --- |")
    clock = time.perf_counter()
    for number in chosen:
        getattr(cases, f"case_{number}")()
    print(f"\n{len(cases.rows)} outcomes in {time.perf_counter() - clock:.0f} s ({work})")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
