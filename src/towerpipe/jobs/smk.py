"""Glue for the thin workflow scripts: logging to the rule's log, one-line errors.

Every script in ``workflow/scripts/`` is::

    from towerpipe.jobs.smk import run_step
    run_step(snakemake, lambda: some_library_call(snakemake.input..., ...))
"""

from __future__ import annotations

import json
import logging
import os
import sys
import traceback
from collections.abc import Callable
from typing import Any

from towerpipe.errors import TowerpipeError


def run_step(smk: Any, step: Callable[[], Any]) -> Any:
    """Run one library call for a Snakemake job.

    Logging goes to the job's ``log`` file. A :class:`TowerpipeError` becomes a
    one-line message (naming file and cause) on stderr and in the log, and exit
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
    except TowerpipeError as exc:
        msg = f"{type(exc).__name__}: {exc}"
        log.error(msg)
        print(f"towerpipe: {msg}", file=sys.stderr)
        sys.exit(1)
    except Exception:
        log.error("unexpected failure:\n%s", traceback.format_exc())
        raise
    log.info("done")
    return result
