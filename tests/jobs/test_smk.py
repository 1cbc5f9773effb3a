"""Tests of towerpipe.jobs.smk: the glue of the workflow's scripts and hooks."""

from __future__ import annotations

import threading
import time

from towerpipe.jobs.smk import stop_rate_limiter_timers


def test_pending_timers_are_cancelled_and_not_run():
    """The scheduler's last timer would keep the interpreter alive for its timespan."""
    fired = threading.Event()
    timer = threading.Timer(60.0, fired.set)
    timer.start()
    t0 = time.perf_counter()
    assert stop_rate_limiter_timers() >= 1
    timer.join(timeout=5.0)
    assert not timer.is_alive() and time.perf_counter() - t0 < 5.0
    assert not fired.is_set()
    assert stop_rate_limiter_timers() == 0
