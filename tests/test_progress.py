"""Tests of towerpipe.progress: counts, rate and ETA lines in the job's log."""

from __future__ import annotations

import logging

from towerpipe.progress import Progress


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_lines_with_rate_and_eta_at_most_every_interval(caplog):
    clock = Clock()
    caplog.set_level(logging.INFO, logger="towerpipe")
    p = Progress("split b1, read", 10_000_000, "points", interval=10.0, clock=clock)
    for _ in range(10):
        clock.t += 4.0  # 1 M points every 4 s
        p.update(1_000_000)
    p.close()
    lines = [r.getMessage() for r in caplog.records]
    # first update, then every >= 10 s (t = 4, 16, 28, 40), then the closing line
    assert lines[0] == "split b1, read: 1.00M/10.0M points (10 %), 250k points/s, ETA 00:36"
    assert lines[1].startswith("split b1, read: 4.00M/10.0M points (40 %), 250k points/s, ETA 00:24")
    assert len(lines) == 5
    assert lines[-1] == "split b1, read: 10.0M points in 40.0 s (250k points/s)"


def test_small_counts_unknown_total_and_context(caplog):
    clock = Clock()
    caplog.set_level(logging.INFO, logger="towerpipe")
    with Progress("infer b1/0_0", None, "windows", interval=0.0, clock=clock) as p:
        clock.t += 2.0
        p.update(5)
    lines = [r.getMessage() for r in caplog.records]
    assert lines == ["infer b1/0_0: 5 windows, 2.5 windows/s", "infer b1/0_0: 5 windows in 2.0 s (2.5 windows/s)"]


def test_no_eta_before_any_time_passed(caplog):
    caplog.set_level(logging.INFO, logger="towerpipe")
    p = Progress("qa b1", 3, "towers", clock=lambda: 0.0)
    p.update()
    assert caplog.records[0].getMessage() == "qa b1: 1/3 towers (33 %), ? towers/s, ETA ?"


def test_steps_without_rate_but_with_what_was_done(caplog):
    clock = Clock()
    caplog.set_level(logging.INFO, logger="towerpipe")
    p = Progress("preprocess z/b/0_0", 4, "stages", interval=0.0, show_rate=False, clock=clock)
    clock.t += 3.0
    p.update(detail="ground took 3.0 s")
    p.close()
    assert [r.getMessage() for r in caplog.records] == [
        "preprocess z/b/0_0: 1/4 stages (25 %), ETA 00:09, ground took 3.0 s",
        "preprocess z/b/0_0: 1 stages in 3.0 s",
    ]
