"""Tests of towerpipe.jobs.smk: the glue of the workflow's scripts and of the Snakefile."""

from __future__ import annotations

import subprocess
import sys
import textwrap
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


def test_the_exit_does_not_wait_for_a_pending_timer():
    """A process whose main thread ends with a timer pending exits at once, the timer not run
    (a Snakemake, the main one or a SLURM job's, after its last scheduling round)."""
    script = textwrap.dedent(
        """
        import threading
        from towerpipe.jobs.smk import stop_timers_at_exit
        assert stop_timers_at_exit() is stop_timers_at_exit()  # one per process
        threading.Timer(20.0, lambda: print("fired", flush=True)).start()
        print("main done", flush=True)
        """
    )
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    assert time.perf_counter() - t0 < 10.0
    assert out.stdout.split() == ["main", "done"]
