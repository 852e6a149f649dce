"""A one-line progress display for long commands: the stage, its progress and its ETA.

The ETA of a stage is extrapolated from its own rate, ``eta = elapsed * (total - done) / done``;
``later_s`` (an estimate of the stages still to come) gives the ETA of the whole command. On a
terminal the line is redrawn in place; otherwise (a log file, a test) a line is printed at most
every ``log_interval_s`` seconds and at the end of each stage.
"""

from __future__ import annotations

import sys
import time


def format_duration(seconds: float, unit: bool = False) -> str:
    """A duration as a clock: ``"mm:ss"`` below an hour, ``"h:mm:ss"`` from an hour on; ``"--:--"``
    when unknown. With ``unit`` the clock says which it is: ``"07:48 (min:s)"``,
    ``"1:27:58 (h:min:s)"``. The one formatter of the durations the console and the reports print."""
    if seconds is None or seconds != seconds or seconds < 0 or seconds == float("inf"):
        return "--:--"
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    clock = f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes:02d}:{secs:02d}"
    if not unit:
        return clock
    return clock + (" (h:min:s)" if hours else " (min:s)")


class StageProgress:
    """``progress.start(stage, total)``, then ``advance``/``set``, then ``finish``."""

    def __init__(self, command: str, stream=None, enabled: bool = True, log_interval_s: float = 15.0) -> None:
        self.command = command
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.interactive = bool(getattr(self.stream, "isatty", lambda: False)())
        self.log_interval_s = log_interval_s
        self.stage = ""
        self.total = 1.0
        self.done = 0.0
        self.later_s = 0.0
        self.detail = ""
        self._stage_start = time.perf_counter()
        self._last_print = 0.0
        self._eta_override: float | None = None

    def start(self, stage: str, total: float, later_s: float = 0.0, detail: str = "") -> None:
        """Begin ``stage`` of ``total`` units (0 done; the clock restarts) and show its line at once.
        ``later_s``: estimated seconds of the stages still to come after this one; ``detail``: extra text."""
        self.stage, self.total, self.done, self.later_s, self.detail = (
            stage,
            max(float(total), 1e-9),
            0.0,
            later_s,
            detail,
        )
        self._stage_start = time.perf_counter()
        self._last_print = 0.0
        self._eta_override = None
        self._show(force=True)

    def eta_s(self) -> float:
        """Seconds left in the stage: the ``eta_s`` given to :meth:`set` if any, else
        ``elapsed * (total - done) / done``; NaN before any progress."""
        if self._eta_override is not None:
            return self._eta_override
        elapsed = time.perf_counter() - self._stage_start
        if self.done <= 0:
            return float("nan")
        return elapsed * max(self.total - self.done, 0.0) / self.done

    def set(
        self, done: float, detail: str | None = None, total: float | None = None, eta_s: float | None = None
    ) -> None:
        """Progress ``done`` of ``total``; ``eta_s`` replaces the extrapolated ETA (e.g. parallel jobs)."""
        self.done = float(done)
        self._eta_override = eta_s
        if total is not None:
            self.total = max(float(total), 1e-9)
        if detail is not None:
            self.detail = detail
        self._show()

    def advance(self, amount: float = 1.0, detail: str | None = None) -> None:
        """``set(done + amount, detail)``: the extrapolated ETA replaces any given one."""
        self.set(self.done + amount, detail)

    def finish(self, message: str = "") -> None:
        """End the stage: mark it complete and write ``<command> | <stage>: done in mm:ss`` (and ``| message``)
        as a final line."""
        elapsed = time.perf_counter() - self._stage_start
        self.done = self.total
        self._write(
            f"{self.command} | {self.stage}: done in {format_duration(elapsed)}" + (f" | {message}" if message else ""),
            final=True,
        )

    def note(self, message: str) -> None:
        """A line of its own (e.g. a skipped method)."""
        self._write(f"{self.command} | {message}", final=True)

    # -- output --------------------------------------------------------------------------
    def line(self) -> str:
        """The progress line ``command | stage | detail | pp%  ETA mm:ss (all mm:ss)``: the percentage is capped
        at 100, the detail only when set, the whole command's ETA (stage ETA + ``later_s``) only when
        ``later_s > 0``."""
        percent = 100.0 * min(self.done / self.total, 1.0)
        eta = self.eta_s()
        total_eta = eta + self.later_s if eta == eta else float("nan")
        parts = [self.command, self.stage]
        if self.detail:
            parts.append(self.detail)
        parts.append(
            f"{percent:3.0f}%  ETA {format_duration(eta)}"
            + (f" (all {format_duration(total_eta)})" if self.later_s > 0 else "")
        )
        return " | ".join(parts)

    def _show(self, force: bool = False) -> None:
        now = time.perf_counter()
        interval = 0.5 if self.interactive else self.log_interval_s
        if force or now - self._last_print >= interval:
            self._last_print = now
            self._write(self.line())

    def _write(self, text: str, final: bool = False) -> None:
        if not self.enabled:
            return
        if self.interactive:
            self.stream.write("\r\033[K" + text + ("\n" if final else ""))
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
