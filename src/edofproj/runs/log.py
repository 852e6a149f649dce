"""The per-step training log: ``train_log.csv`` (and TensorBoard scalars when installed).

Columns: ``step`` (1-based optimizer step), ``loss`` (the training objective of Eq. 12 on the
global batch), ``mse`` and ``perceptual`` (its two terms before weighting; empty when a
term is not computed), ``lr`` (the network's learning rate at that step, or the DOE's when
the network is frozen) and ``seconds`` (training wall time since the run started, summed
over resumed sessions). The file is appended and flushed every step; when a run resumes
from a checkpoint, rows after the checkpoint's step are dropped first, so the log always
describes one uninterrupted run. (``metrics.csv`` is reserved for ``edofproj evaluate``.)
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from ..fileio import write_text_atomic

LOG_NAME = "train_log.csv"
COLUMNS = ("step", "loss", "mse", "perceptual", "lr", "seconds")


def _format(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    if isinstance(value, int):
        return str(value)
    return f"{float(value):.8g}"


def read_log(path: str | Path) -> list[dict[str, float]]:
    """Rows of a training log as dictionaries of floats (``nan`` for empty cells)."""
    path = Path(path)
    if not path.is_file():
        return []
    rows = []
    with path.open(newline="", encoding="utf-8") as handle:
        for row in csv.DictReader(handle):
            rows.append({k: (float(v) if v not in ("", None) else math.nan) for k, v in row.items()})
    return rows


class TrainingLog:
    """Append-only CSV log (plus optional TensorBoard) of a run directory."""

    def __init__(self, run_dir: str | Path, resume_step: int = 0, tensorboard: bool = True) -> None:
        self.path = Path(run_dir) / LOG_NAME
        self._truncate_after(resume_step)
        new_file = not self.path.is_file()
        self._handle = self.path.open("a", newline="", encoding="utf-8")
        self._writer = csv.writer(self._handle)
        if new_file:
            self._writer.writerow(COLUMNS)
            self._handle.flush()
        self._tensorboard = _tensorboard_writer(Path(run_dir) / "tensorboard") if tensorboard else None

    def _truncate_after(self, step: int) -> None:
        """Keep the header and the rows with ``step <= step`` (atomically rewritten)."""
        if not self.path.is_file():
            return
        lines = self.path.read_text(encoding="utf-8").splitlines()
        if not lines:
            self.path.unlink()
            return
        kept = [lines[0]] + [line for line in lines[1:] if line and int(float(line.split(",")[0])) <= step]
        write_text_atomic(self.path, "\n".join(kept) + "\n")

    def write(
        self, step: int, loss: float, mse: float | None, perceptual: float | None, lr: float, seconds: float
    ) -> None:
        self._writer.writerow([_format(v) for v in (int(step), loss, mse, perceptual, lr, seconds)])
        self._handle.flush()
        if self._tensorboard is not None:
            for name, value in (("loss", loss), ("mse", mse), ("perceptual", perceptual), ("lr", lr)):
                if value is not None and not math.isnan(value):
                    self._tensorboard.add_scalar(f"train/{name}", value, step)

    def close(self) -> None:
        self._handle.close()
        if self._tensorboard is not None:
            self._tensorboard.close()


def _tensorboard_writer(directory: Path):
    """A ``SummaryWriter`` when TensorBoard is installed, else None."""
    try:
        from torch.utils.tensorboard import SummaryWriter  # optional: TensorBoard
    except ImportError:
        return None
    return SummaryWriter(log_dir=str(directory))
