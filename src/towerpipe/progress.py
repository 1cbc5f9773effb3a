"""Progress of long jobs in their rule log: counts, rate and ETA, a line every few seconds.

A job logs to its rule log (``work/<zone>/logs/<rule>/…``, see :func:`towerpipe.jobs.smk.run_step`),
so an operator following a run (``tail -f``) sees what each job is doing::

    split 400000_4600000: 2.00M/9.85M points (20 %), 625k points/s, ETA 00:12
    infer 400000_4600000/0_0: 120/784 windows (15 %), 41.2 windows/s, ETA 00:16
    split 400000_4600000: 9.85M points in 15.9 s (620k points/s)

Usage::

    progress = Progress("merge b1", total=n_points, unit="points", logger=log)
    for chunk in chunks:
        ...
        progress.update(len(chunk))
    progress.close()

The numbers are formatted with tqdm's helpers; the lines go through :mod:`logging`.
"""

from __future__ import annotations

import logging
import resource
import sys
import time
from collections.abc import Callable
from typing import Any

from tqdm import tqdm

#: Seconds between two progress lines of one job (the first and the last are always logged).
LOG_INTERVAL_S = 10.0


def _count(n: float, scale: bool) -> str:
    if scale:
        return tqdm.format_sizeof(n, divisor=1000).strip()
    return f"{n:,.1f}" if isinstance(n, float) and n < 100 else f"{int(n):,}"


class Progress:
    """Counts of a long loop, logged as ``what: n/total unit (p %), rate unit/s, ETA mm:ss``.

    Parameters
    ----------
    what
        What is being done (e.g. ``"split b1"``), the start of each line.
    total
        Expected count (None when unknown: no percentage or ETA).
    unit
        What is counted (``"points"``, ``"windows"``, ``"tiles"`` …).
    logger
        Where the lines go (default: the ``towerpipe`` logger).
    interval
        Seconds between two lines at least.
    scale
        Counts as ``2.00M`` rather than ``2,000,000`` (default: when ``total`` ≥ 10,000).
    show_rate
        Put the rate in the lines (off for a few uneven steps, e.g. the stages of a tile:
        the ETA still comes from the average step).
    clock
        Time source (monotonic seconds).
    """

    def __init__(
        self,
        what: str,
        total: int | None = None,
        unit: str = "items",
        *,
        logger: logging.Logger | None = None,
        interval: float = LOG_INTERVAL_S,
        scale: bool | None = None,
        show_rate: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.what, self.total, self.unit = what, total, unit
        self.log = logger or logging.getLogger("towerpipe")
        self.interval = interval
        self.scale = (total or 0) >= 10_000 if scale is None else scale
        self.clock = clock
        self.show_rate = show_rate
        self.n = 0
        self.start = clock()
        self._last: float | None = None
        self.closed = False

    def rate(self) -> float:
        """Units per second so far."""
        elapsed = self.clock() - self.start
        return self.n / elapsed if elapsed > 0 else float("nan")

    def line(self, detail: str = "") -> str:
        """The progress line for now (``detail`` appended, e.g. the step just done)."""
        rate = self.rate()
        parts = []
        if self.show_rate:
            parts.append(f"{_count(rate, self.scale)} {self.unit}/s" if rate == rate else f"? {self.unit}/s")
        if self.total:
            eta = (self.total - self.n) / rate if rate and rate == rate else None
            parts.append(f"ETA {tqdm.format_interval(eta) if eta is not None else '?'}")
            head = (
                f"{self.what}: {_count(self.n, self.scale)}/{_count(self.total, self.scale)} {self.unit} "
                f"({100.0 * self.n / self.total:.0f} %)"
            )
        else:
            head = f"{self.what}: {_count(self.n, self.scale)} {self.unit}"
        return ", ".join([head, *parts, *([detail] if detail else [])])

    def update(self, n: int = 1, detail: str = "") -> None:
        """Count ``n`` more; logs a line when ``interval`` has passed since the last one."""
        self.n += int(n)
        now = self.clock()
        if self._last is None or now - self._last >= self.interval:
            self._last = now
            self.log.info("%s", self.line(detail))

    def close(self) -> None:
        """Log the final line: the count, the time taken and the rate."""
        if self.closed:
            return
        self.closed = True
        elapsed = self.clock() - self.start
        rate = (
            f" ({_count(self.n / elapsed, self.scale)} {self.unit}/s)"
            if self.show_rate and elapsed > 0 and self.n
            else ""
        )
        self.log.info("%s: %s %s in %.1f s%s", self.what, _count(self.n, self.scale), self.unit, elapsed, rate)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: Any) -> None:
        if exc[0] is None:
            self.close()


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MiB (``ru_maxrss`` is KiB on Linux, bytes on macOS)."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / (1024 * 1024) if sys.platform == "darwin" else r / 1024
