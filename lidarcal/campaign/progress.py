"""How a long simulation says where it is: a live bar on a terminal, a line at a steady interval elsewhere.

A campaign runs for minutes to hours; its chunks finish one by one.  :class:`Progress` says how
the run reports them:

* ``"bar"``: a live tqdm bar on stderr (the command line's default on a terminal);
* ``"lines"``: every :data:`PROGRESS_INTERVAL` seconds (``interval``) one INFO line on the
  ``lidarcal.campaign.progress`` logger, which the command line prints on stderr: periods done of
  the total, chunks, time so far and an estimate of the time left, e.g.
  ``replica 0: 1280 of 2016 periods (63 %), 20 of 32 chunks; 2 min 10 s so far, about 1 min 15 s
  left`` (the default without a terminal: under ``tee``, ``nohup``, a batch job or CI, where a
  bar would print nothing readable);
* ``"off"``: nothing.

The estimate is the rate at which this run's chunks have been finishing since the first one did
(the workers' start-up before it is not a rate), applied to the periods left; chunks reused
from an interrupted run are not among the tasks at all.  One :class:`Progress` serves a
whole command: its :meth:`~Progress.tracker` follows one set of tasks (replica 0, then each
batch of replicas, labelled by :meth:`~Progress.labelled`), and :meth:`~Progress.once` prints a
message (a dask dashboard link) once however many sets of tasks follow.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from typing import Any

from lidarcal.errors import InputError

__all__ = ["Progress", "Tracker", "PROGRESS_INTERVAL", "duration_text"]

log = logging.getLogger(__name__)

#: Seconds between two progress lines (``"lines"`` mode).
PROGRESS_INTERVAL = 30.0
_MODES = ("bar", "lines", "off")


def duration_text(seconds: float) -> str:
    """``'45 s'``, ``'2 min 05 s'``, ``'1 h 03 min'``: a duration as people read it."""
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


@dataclasses.dataclass(frozen=True)
class Progress:
    """How a simulation reports its progress: ``mode`` ``"bar"``, ``"lines"`` or ``"off"``.

    ``interval`` is the seconds between two lines; ``label`` names the set of tasks in each
    line (``"replica 0"``, ``"replicas 4-7 (of at most 30)"``).
    """

    mode: str = "lines"
    interval: float = PROGRESS_INTERVAL
    label: str = "simulation"
    _said: set = dataclasses.field(default_factory=set, compare=False, repr=False)
    #: when the last line was logged (or the first set of tasks started), shared by every label
    _last: list = dataclasses.field(default_factory=list, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in _MODES:
            raise InputError(f"progress mode {self.mode!r}; expected one of {', '.join(_MODES)}")
        if not self.interval > 0:
            raise InputError(f"progress interval must be > 0 s; got {self.interval!r}")

    @classmethod
    def of(cls, progress: Any) -> Progress:
        """Return ``progress`` as a :class:`Progress` (True: a bar; False, None: nothing; or a mode)."""
        if isinstance(progress, Progress):
            return progress
        if progress is None or progress is False:
            return cls("off")
        if progress is True:
            return cls("bar")
        if isinstance(progress, str):
            return cls(progress)
        raise InputError(f"progress must be a bool, one of {', '.join(_MODES)} or a Progress; "
                         f"got {progress!r}")

    def labelled(self, label: str) -> Progress:
        """Return the same reporting for another set of tasks (what :meth:`once` said stays said)."""
        return dataclasses.replace(self, label=label, _said=self._said, _last=self._last)

    def once(self, message: str) -> None:
        """Log ``message`` (INFO) unless this :class:`Progress` has logged it already."""
        if message not in self._said:
            self._said.add(message)
            log.info("%s", message)

    def tracker(self, periods: int, chunks: int) -> Tracker:
        """Return a :class:`Tracker` of ``chunks`` tasks holding ``periods`` periods in all."""
        return Tracker(self, int(periods), int(chunks))


class Tracker:
    """Follows one set of chunk tasks: ``with progress.tracker(n, m) as t: ... t.done(periods)``.

    In ``"lines"`` mode a daemon thread logs a line every ``interval`` seconds while the tasks
    run (so a line comes even when no chunk finishes for a while), and a last line when the set
    ends if it logged one.  The interval runs from the last line of any set of the same
    :class:`Progress` (or the start of its first set): a run of many short sets (the model-form
    alternatives, small batches of replicas) still says where it is every ``interval`` seconds.
    """

    def __init__(self, progress: Progress, periods: int, chunks: int) -> None:
        self.progress = progress
        self.periods, self.chunks = periods, chunks
        self.periods_done = self.chunks_done = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bar: Any = None
        self._said_done = -1  # periods done at the last line logged (-1: none logged)
        self._first: tuple[float, int] | None = None  # (time, periods done) when the first chunk finished
        self._t0 = time.monotonic()

    def __enter__(self) -> Tracker:
        self._t0 = time.monotonic()
        if not self.progress._last:
            self.progress._last.append(self._t0)
        if self.progress.mode == "bar":
            from tqdm.auto import tqdm

            self._bar = tqdm(total=self.periods, unit="period", desc=self.progress.label, dynamic_ncols=True)
        elif self.progress.mode == "lines" and self.chunks:
            self._thread = threading.Thread(target=self._loop, name="lidarcal-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._bar is not None:
            self._bar.close()
        if exc_type is None and 0 <= self._said_done < self.periods_done:  # a long set: say it ended
            self._say()

    def done(self, periods: int) -> None:
        """Count one finished chunk of ``periods`` periods."""
        with self._lock:
            if self._first is None:
                self._first = (time.monotonic(), int(periods))
            self.periods_done += int(periods)
            self.chunks_done += 1
        if self._bar is not None:
            self._bar.update(int(periods))

    def line(self) -> str:
        """Return the progress line: periods and chunks done, time so far, the estimate of the time left."""
        with self._lock:
            done, chunks_done, first = self.periods_done, self.chunks_done, self._first
        now = time.monotonic()
        elapsed = now - self._t0
        pct = 100.0 * done / self.periods if self.periods else 100.0
        head = (f"{self.progress.label}: {done} of {self.periods} periods ({pct:.0f} %), "
                f"{chunks_done} of {self.chunks} chunks; {duration_text(elapsed)} so far")
        if done >= self.periods:
            return f"{head}, done"
        if not done:
            return f"{head}, no chunk finished yet to estimate the time left"
        t1, n1 = first if first is not None else (self._t0, 0)
        since, rate_of = (now - t1, done - n1) if done > n1 and now - t1 >= 1.0 else (elapsed, done)
        return f"{head}, about {duration_text(since / rate_of * (self.periods - done))} left"

    def _say(self) -> None:
        self._said_done = self.periods_done
        self.progress._last[0] = time.monotonic()
        log.info("%s", self.line())

    def _loop(self) -> None:
        interval = self.progress.interval
        while not self._stop.wait(min(interval / 4, 1.0)):
            if time.monotonic() - self.progress._last[0] >= interval:
                self._say()
