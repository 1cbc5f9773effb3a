"""Glue for the thin workflow scripts (logging to the rule's log, one-line errors) and for the
Snakefile (:func:`stop_timers_at_exit`).

Every script in ``workflow/scripts/`` is::

    from towerpipe.jobs.smk import run_step
    run_step(snakemake, lambda: some_library_call(snakemake.input..., ...))
"""

from __future__ import annotations

import ctypes
import json
import logging
import os
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Any

from towerpipe.errors import TowerpipeError
from towerpipe.io.diskspace import full_disk_error

#: glibc's ``mallopt`` parameters (``malloc.h``) and what a job sets them to (:func:`keep_freed_memory`).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
#: An allocation this large or larger gets a mapping of its own (glibc's highest value: 32 MiB).
MMAP_THRESHOLD = 32 * 1024**2
#: Free memory at the top of the heap that is kept for the next allocations rather than handed back.
TRIM_THRESHOLD = 1024**3


def keep_freed_memory() -> bool:
    """Have glibc's allocator keep what a job frees for its next arrays; ``False`` where the C
    library has no ``mallopt`` (not glibc) or refuses a value.

    A job's arrays of a tile's points are 1-30 MB, and the job makes and drops hundreds of them.
    By default glibc maps each such array afresh (or hands the top of the heap back once more than
    twice the largest freed mapping is free), so the kernel zeroes and maps every page of every
    new array again: 1.23 M page faults and 7-8 s of system time over a run of the bench block
    (``python -m towerpipe.bench e2e``). Arrays up to :data:`MMAP_THRESHOLD` now come from the heap,
    and up to :data:`TRIM_THRESHOLD` of freed heap is kept for reuse (docs/scale.md).
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))


def run_step(smk: Any, step: Callable[[], Any]) -> Any:
    """Run one library call for a Snakemake job.

    Logging goes to the job's ``log`` file. A :class:`TowerpipeError`, and an error of a
    full disk wherever it is raised (:func:`towerpipe.io.diskspace.full_disk_error`), becomes
    a one-line message (naming file and cause) on stderr and in the log, and exit
    status 1; Snakemake then removes the job's outputs, so nothing that looks
    complete survives. Any other exception is logged with its traceback.
    """
    log_file = smk.log[0] if len(smk.log) else None
    handlers: list[logging.Handler] = [logging.StreamHandler(sys.stderr)]
    if log_file:
        handlers.append(logging.FileHandler(log_file, mode="w"))
    logging.basicConfig(
        level=logging.INFO, handlers=handlers, force=True, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    keep_freed_memory()
    threads = int(getattr(smk, "threads", 1) or 1)
    # the LAZ codec's thread pool (lazrs, Rayon) would take every core of the machine: it gets
    # the job's threads, as NumPy's and PyTorch's pools do (its pool starts on first use)
    os.environ["RAYON_NUM_THREADS"] = str(threads)
    torch = sys.modules.get("torch")  # only jobs that use torch pay for importing it
    if torch is not None:
        torch.set_num_threads(threads)
    log = logging.getLogger("towerpipe")
    log.info("job %s: %s", smk.rule, json.dumps({k: str(v) for k, v in smk.wildcards.items()}))
    try:
        result = step()
    except Exception as exc:
        # a full disk is no bug: said in one line wherever in the job it was met, whatever
        # error a library made of it
        err = full_disk_error(exc) or (exc if isinstance(exc, TowerpipeError) else None)
        if err is None:
            log.error("unexpected failure:\n%s", traceback.format_exc())
            raise
        msg = f"{type(err).__name__}: {err}"
        log.error(msg)
        print(f"towerpipe: {msg}", file=sys.stderr)
        sys.exit(1)
    log.info("done")
    return result


def stop_rate_limiter_timers() -> int:
    """Cancel the pending :class:`threading.Timer` threads of this process; returns how many.

    After each round of scheduling, Snakemake's job rate limiter (``--max-jobs-per-timespan``,
    100 jobs a second by default) arms a ``threading.Timer`` of its timespan (1 s) that wakes the
    scheduler again. The timer is not a daemon thread, so the interpreter waits for the last one
    before it exits: up to a second at the end of every run (1.2 s from the last job's end to the
    exit on the bench zone, 0.3 s with the timers cancelled). Called once the run is over
    (:func:`stop_timers_at_exit`), when no job is left to wake the scheduler for.
    """
    timers = [t for t in threading.enumerate() if isinstance(t, threading.Timer) and t.is_alive()]
    for t in timers:
        t.cancel()
    return len(timers)


_reaper: threading.Thread | None = None


def stop_timers_at_exit() -> threading.Thread:
    """Have the interpreter's exit cancel the pending timers (:func:`stop_rate_limiter_timers`)
    instead of waiting for them; returns the daemon thread that does it (one per process).

    The thread waits for the main thread to end: the interpreter ends it first when it exits, then
    waits for the threads that are not daemons, the timers among them. The Snakefile starts it, so
    it works in every Snakemake that reads the Snakefile: the main one, and the one each SLURM job
    starts on its node, which runs no ``onsuccess`` hook.
    """
    global _reaper
    if _reaper is None:  # it lives until the interpreter exits
        main = threading.main_thread()

        def reap() -> None:
            main.join()
            stop_rate_limiter_timers()

        _reaper = threading.Thread(target=reap, name="towerpipe-stop-timers", daemon=True)
        _reaper.start()
    return _reaper
