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


def test_a_job_keeps_the_memory_it_frees_for_its_next_arrays():
    """Arrays of a tile's size, made again after they were freed, land on pages already mapped
    once the job has set glibc's allocator (every job does, through run_step): no page is mapped
    and zeroed again."""
    script = textwrap.dedent(
        """
        import resource
        import numpy as np
        from towerpipe.jobs.smk import keep_freed_memory

        def faults_of_arrays_made_again():
            arrays = [np.ones(2_500_000) for _ in range(4)]  # four of 20 MB, freed together
            del arrays
            before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            arrays = [np.ones(2_500_000) for _ in range(4)]
            del arrays
            return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

        plain = faults_of_arrays_made_again()
        assert keep_freed_memory()
        faults_of_arrays_made_again()  # the heap grows to hold them once
        print(plain, faults_of_arrays_made_again())
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    plain, kept = (int(v) for v in out.stdout.split())
    assert plain > 100 and kept < plain / 10
