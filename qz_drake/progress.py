"""Progress of the long runs, shown the same way by every command (DESIGN.md, "Ours" item 6).

A run reports on stderr, so that a command's JSON on stdout stays parseable:

* on a terminal, a rich bar with the amount done, the elapsed time and an ETA;
* anywhere else (a pipe, a ``nohup`` log, a notebook), no animation: one plain line at most
  every ``PLAIN_LINE_INTERVAL`` seconds, so that a background run's log stays readable;
* disabled (``--json``), nothing at all.

A report only displays numbers its caller already has; it never feeds anything back into the
run it describes.
"""

from __future__ import annotations

import math
import time

# Seconds between two plain lines in a log: the 150 s demo writes five, an 8-minute stance
# collection sixteen.
PLAIN_LINE_INTERVAL = 30.0


# Seconds between two redraws of a bar at most. The bar is redrawn by the thread that reports
# progress, never by a thread of its own: a garbage collection that runs in another thread frees
# the Drake objects it finds there, off the thread that made them (a `make test` worker aborted,
# "Fatal Python error: Aborted", while rich's refresh thread was collecting garbage during a
# simulation; Drake's Meshcat, for one, must be used from the thread that made it).
REDRAW_PERIOD = 0.1

# Seconds of the recent past a bar's ETA takes the speed from. Rich's 30 s default sees no
# progress at all within a 2-minute network or walk mission, and shows no ETA.
SPEED_PERIOD = 600.0


def stderr_console():
    """The rich Console every progress display draws on: stderr, never stdout."""
    from rich.console import Console

    return Console(stderr=True)


def bar_columns() -> tuple:
    """The columns of every bar: what runs, the bar, the amount done, elapsed time, ETA, status.
    The task fields ``amount`` and ``status`` are the caller's text."""
    from rich.progress import BarColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    return (TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[amount]}"),
            TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), TextColumn("{task.fields[status]}"))


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class ProgressReport:
    """One progress display: a rich bar on a terminal, plain lines elsewhere, nothing when
    disabled. Use it as a context manager; ``update`` as the run advances.

    Args:
        description: what runs, e.g. ``"demo: walking"``.
        total: the amount the run ends at; None while it is not known (a pulsing bar).
        unit: of the amount, e.g. ``"networks"`` or ``"s simulated"``.
        digits: decimals of the amount shown.
        completed: what was done before this run started (resumed work): shown, but not
            counted in the plain lines' rate and ETA.
        enabled: False (``--json``): no output.
        console: a rich Console to draw on (default: stderr's).
        interval: seconds between plain lines.
    """

    def __init__(self, description: str, total: float | None = None, *, unit: str = "", digits: int = 0,
                 completed: float = 0.0, enabled: bool = True, console=None,
                 interval: float = PLAIN_LINE_INTERVAL):
        self.description, self.total, self.unit, self.digits = description, total, unit, int(digits)
        self.completed = float(completed)
        self.status = ""
        self.enabled = bool(enabled)
        self.interval = float(interval)
        self._start = self._last_line = time.perf_counter()
        # Where the plain lines' rate counts from: the start, or the start of the last stage.
        self._rate_start, self._rate_from = self._start, self.completed
        self._bar = None
        self._console = None
        if not self.enabled:
            return
        self._console = console or stderr_console()
        if self._console.is_terminal:
            from rich.progress import Progress

            self._bar = Progress(*bar_columns(), console=self._console, speed_estimate_period=SPEED_PERIOD,
                                 auto_refresh=False)
            self._redrawn = -math.inf
            self._task = self._bar.add_task(description, total=total, completed=self.completed,
                                            amount=self.amount(), status="")
            self._bar.start()

    def __enter__(self) -> "ProgressReport":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def animated(self) -> bool:
        """Whether a bar is drawn (a terminal), not plain lines."""
        return self._bar is not None

    def amount(self) -> str:
        """The amount done as shown, e.g. ``"12.5/300.0 s simulated"``."""
        done = f"{self.completed:.{self.digits}f}"
        total = "?" if self.total is None else f"{self.total:.{self.digits}f}"
        return f"{done}/{total} {self.unit}".rstrip()

    def eta_seconds(self) -> float | None:
        """Seconds left at the rate of this run so far (since its last stage began, see
        ``begin``); None while it cannot be told."""
        elapsed = time.perf_counter() - self._rate_start
        done = self.completed - self._rate_from
        if self.total is None or done <= 0 or elapsed <= 0:
            return None
        return max(self.total - self.completed, 0.0) * elapsed / done

    def line(self) -> str:
        """The plain line of the current state."""
        percent = "" if not self.total else f" ({100 * min(self.completed / self.total, 1.0):.0f} %)"
        eta = self.eta_seconds()
        status = f", {self.status}" if self.status else ""
        return (f"{self.description}: {self.amount()}{percent}{status}, "
                f"{_clock(time.perf_counter() - self._start)} elapsed"
                + ("" if eta is None or not math.isfinite(eta) else f", ETA {_clock(eta)}"))

    def begin(self, description: str | None = None, completed: float | None = None, *,
              total: float | None = None, status: str | None = None) -> None:
        """A new stage of the run begins (the demo: walking, after building and planning), at
        ``completed`` done (and, where given, the new total, description and status): the ETA
        takes its rate from here on, since what came before went at another pace (the demo's
        planning made its first ETA 1.7 times the time left). A log gets a line at once, so
        that it shows when the stage began."""
        if completed is not None:
            self.completed = float(completed)
        self._rate_start, self._rate_from = time.perf_counter(), self.completed
        self.update(total=total, description=description, status=status, line_now=True)

    def update(self, completed: float | None = None, *, advance: float | None = None, total: float | None = None,
               description: str | None = None, status: str | None = None, line_now: bool = False) -> None:
        """Sets the amount done (or adds ``advance``) and, where given, the total, the
        description and the status text; ``line_now``: a log gets its line now, whatever the
        interval."""
        if completed is not None:
            self.completed = float(completed)
        if advance is not None:
            self.completed += float(advance)
        if total is not None:
            self.total = float(total)
        if description is not None:
            self.description = description
        if status is not None:
            self.status = status
        if self._bar is not None:
            self._bar.update(self._task, completed=self.completed, total=self.total, description=self.description,
                             amount=self.amount(), status=self.status)
            now = time.perf_counter()
            if line_now or now - self._redrawn >= REDRAW_PERIOD:
                self._redrawn = now
                self._bar.refresh()
        elif self.enabled:
            now = time.perf_counter()
            if line_now or now - self._last_line >= self.interval:
                self._last_line = now
                self._console.file.write(self.line() + "\n")
                self._console.file.flush()

    def close(self) -> None:
        """Stops the bar (it stays on the terminal as it ended)."""
        if self._bar is not None:
            self._bar.stop()
            self._bar = None
        self.enabled = False


def simulation_progress(report: ProgressReport, description: str | None = None):
    """A progress hook for qz_drake.simulation.simulate / walk: the simulated time against the
    run's end on ``report`` (a new stage from its first call on, described as ``description``),
    and the missions planned so far."""

    started = False

    def hook(sim_time: float, end_time: float, missions: int | None) -> None:
        nonlocal started
        status = "" if missions is None else f"{missions} missions planned"
        if sim_time >= end_time:
            status = (status + ", " if status else "") + "writing the results"
        if started:
            report.update(sim_time, total=end_time, description=description, status=status)
        else:  # the simulation runs: building the diagram and planning are over
            started = True
            report.begin(description, sim_time, total=end_time, status=status)

    return hook
