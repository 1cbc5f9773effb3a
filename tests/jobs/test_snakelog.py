"""towerpipe.jobs.snakelog: failed blocks and their reasons from Snakemake's main log.

The log snippets are Snakemake 9.27 output (``.snakemake/log/*.snakemake.log``) of a
small failing workflow with the towerpipe log layout (``<work>/<zone>/logs/<rule>/...``).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from towerpipe.jobs.snakelog import failures_from_log

HEADER = """\
Assuming unrestricted shared filesystem usage.

SNAKEMAKE
=========
  Date: 2026-11-23 21:06:21
  Workflow ID: 2abf26fd-3abb-4957-9732-171ffa53f0ae
  Snakemake version: 9.27.1
  Command: /work/main/.venv/bin/snakemake -c1 --keep-going

Building DAG of jobs...
Using shell: /usr/bin/bash
Provided cores: 1 (use --cores to define parallelism)
Rules claiming more threads will be scaled down.
Job stats:
job                count
---------------  -------
preprocess_tile        1
split_block            2
all                    1
total                  4

"""


def _job(rule: str, jobid: int, output: str, log: str, wildcards: str, time: str = "21:06:21") -> str:
    """Snakemake's lines for a job that starts."""
    return f"""\
Select jobs to execute...
Execute 1 jobs...
[Mon Nov 23 {time} 2026]
localrule {rule}:
    output: {output}
    log: {log}
    jobid: {jobid}
    reason: Missing output files: {output}
    wildcards: {wildcards}
    resources: tmpdir=/tmp
"""


def _failed(rule: str, jobid: int, output: str, log: str, wildcards: str, smk_line: int) -> str:
    """Snakemake's lines for a job whose shell command fails."""
    return (
        _job(rule, jobid, output, log, wildcards)
        + f"""\
RuleException:
CalledProcessError in file "/tmp/smklog/workflow/rules/preprocess.smk", line {smk_line}:
Command 'set -euo pipefail;  python workflow/scripts/{rule}.py' returned non-zero exit status 1.
[Mon Nov 23 21:06:21 2026]
Error in rule {rule}:
    message: None
    jobid: {jobid}
    output: {output}
    log: {log} (check log file(s) for error details)
    shell:
        python workflow/scripts/{rule}.py
        (command exited with non-zero exit code)
"""
    )


FAILED_SPLIT = _failed(
    "split_block",
    2,
    "work/demo/cache/broken/meta.json",
    "work/demo/logs/split_block/broken.log",
    "zone=demo, block=broken",
    15,
)

FAILED_TILE = _failed(
    "preprocess_tile",
    3,
    "work/demo/tiles/nir/t0.npz",
    "work/demo/logs/preprocess_tile/nir/t0.log",
    "zone=demo, block=nir, tile=t0",
    32,
)

FINISHED_GOOD = (
    _job(
        "split_block",
        1,
        "work/demo/cache/good/meta.json",
        "work/demo/logs/split_block/good.log",
        "zone=demo, block=good",
    )
    + """\
[Mon Nov 23 21:06:21 2026]
Finished jobid: 1 (Rule: split_block)
1 of 4 steps (25%) done
"""
)

FOOTER = """\
Exiting because a job execution failed. Look above for error messages
Complete log(s): /tmp/smklog/.snakemake/log/2026-11-23T210621.628474.snakemake.log
Elapsed time: 0:00:00.318823
WorkflowError:
At least one job did not complete successfully.
"""

# a run interrupted (Ctrl-C, kill) while a job ran: the log stops inside the job
INTERRUPTED = HEADER + _job(
    "split_block",
    1,
    "work/demo/cache/slow/meta.json",
    "work/demo/logs/split_block/slow.log",
    "zone=demo, block=slow",
    time="21:06:39",
)

# the next run of an interrupted one, without --rerun-incomplete
INCOMPLETE_FILES = """\
Building DAG of jobs...
IncompleteFilesException:
The files below seem to be incomplete. If you are sure that certain files are not incomplete, mark them as complete with

    snakemake --cleanup-metadata <filenames>

To re-generate the files rerun your command with the --rerun-incomplete flag.
Incomplete files:
work/demo/cache/slow/meta.json
"""

SPLIT_LOG = """\
2026-11-23 21:06:21,100 INFO towerpipe: job split_block: {"zone": "demo", "block": "broken"}
2026-11-23 21:06:21,200 ERROR towerpipe: InputError: data/demo/broken.laz: not a LAS/LAZ file (bad signature)
"""

TILE_LOG = """\
2026-11-23 21:06:21,300 INFO towerpipe: job preprocess_tile: {"zone": "demo", "block": "nir", "tile": "t0"}
2026-11-23 21:06:22,000 ERROR towerpipe: unexpected failure:
Traceback (most recent call last):
  File "/work/main/src/towerpipe/jobs/smk.py", line 40, in run_step
    result = step()
numpy.core._exceptions._ArrayMemoryError: Unable to allocate 3.20 GiB for an array with shape (430000000,)

"""


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def run_dir(tmp_path, monkeypatch):
    """A run directory: Snakemake prints job log paths relative to it."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_failed_jobs_with_their_towerpipe_error(run_dir):
    main = _write(
        run_dir / ".snakemake/log/main.snakemake.log", HEADER + FAILED_SPLIT + FAILED_TILE + FINISHED_GOOD + FOOTER
    )
    _write(run_dir / "work/demo/logs/split_block/broken.log", SPLIT_LOG)
    _write(run_dir / "work/demo/logs/preprocess_tile/nir/t0.log", TILE_LOG)
    _write(run_dir / "work/demo/logs/split_block/good.log", "2026-11-23 21:06:21,400 INFO towerpipe: done\n")
    failures = failures_from_log(main, "work")
    # the logger prefix is cut; a tile's log names its block (the directory)
    assert failures == {
        "demo": {
            "broken": "split_block: InputError: data/demo/broken.laz: not a LAS/LAZ file (bad signature)",
            "nir": "preprocess_tile: numpy.core._exceptions._ArrayMemoryError: Unable to allocate 3.20 GiB for an "
            "array with shape (430000000,)",
        }
    }
    # the work directory given as an absolute path, the log as a str: the same
    assert failures_from_log(str(main), str(run_dir / "work")) == failures


def test_reason_without_an_error_line_or_a_job_log(run_dir):
    main = _write(run_dir / "smk.log", HEADER + FAILED_SPLIT + FAILED_TILE + FOOTER)
    # no "...Error: " line: the last non-empty line; no job log at all: "<rule> failed"
    _write(run_dir / "work/demo/logs/split_block/broken.log", "pdal: killed by signal 9\n\n  \n")
    assert failures_from_log(main, "work") == {
        "demo": {"broken": "split_block: pdal: killed by signal 9", "nir": "preprocess_tile failed"}
    }
    # an empty job log gives "<rule> failed" too
    _write(run_dir / "work/demo/logs/split_block/broken.log", "")
    assert failures_from_log(main, "work")["demo"]["broken"] == "split_block failed"


def test_reason_is_cut_to_300_characters(run_dir):
    main = _write(run_dir / "smk.log", HEADER + FAILED_SPLIT + FOOTER)
    cause = "x" * 400
    _write(
        run_dir / "work/demo/logs/split_block/broken.log",
        f"2026-11-23 21:06:21,200 ERROR towerpipe: InputError: {cause}\n",
    )
    reason = failures_from_log(main, "work")["demo"]["broken"]
    assert reason == "split_block: " + ("InputError: " + cause)[:300]


def test_interrupted_run_has_no_failures(run_dir):
    # a run stopped inside a job, and the next one refusing the incomplete files: no
    # "Error in rule" block, so no failed block (the zone is not published as INCOMPLETE)
    main = _write(run_dir / "a.log", INTERRUPTED)
    nxt = _write(run_dir / "b.log", HEADER + INCOMPLETE_FILES)
    _write(run_dir / "work/demo/logs/split_block/slow.log", "started\n")
    assert failures_from_log([main, nxt], "work") == {}


def test_several_logs_first_reason_kept_and_missing_logs_ignored(run_dir):
    first = _write(run_dir / "1.log", HEADER + FAILED_SPLIT + FOOTER)
    second = _write(run_dir / "2.log", HEADER + FAILED_SPLIT.replace("split_block", "towers_block") + FOOTER)
    _write(run_dir / "work/demo/logs/split_block/broken.log", SPLIT_LOG)
    _write(run_dir / "work/demo/logs/towers_block/broken.log", "ValueError: later\n")
    out = failures_from_log([first, second, run_dir / "missing.log"], "work")
    assert out == {
        "demo": {"broken": "split_block: InputError: data/demo/broken.laz: not a LAS/LAZ file (bad signature)"}
    }
    assert failures_from_log([], "work") == {}
    assert failures_from_log(run_dir / "missing.log", "work") == {}


def test_logs_that_name_no_block_are_skipped(run_dir):
    zone_job = FAILED_SPLIT.replace("split_block", "plan_zone").replace(
        "logs/plan_zone/broken.log", "logs/plan_zone.log"
    )
    elsewhere = FAILED_SPLIT.replace("work/demo/logs", "other/demo/logs")
    main = _write(run_dir / "smk.log", HEADER + zone_job + elsewhere + FOOTER)
    _write(run_dir / "work/demo/logs/plan_zone.log", "ConfigError: bad\n")
    _write(run_dir / "other/demo/logs/split_block/broken.log", "InputError: x\n")
    assert failures_from_log(main, "work") == {}


def test_zones_are_kept_apart(run_dir):
    other = FAILED_SPLIT.replace("work/demo/", "work/north/").replace("broken", "b7")
    main = _write(run_dir / "smk.log", HEADER + FAILED_SPLIT + other + FOOTER)
    assert failures_from_log(main, "work") == {
        "demo": {"broken": "split_block failed"},
        "north": {"b7": "split_block failed"},
    }


def test_log_of_a_real_snakemake_run(run_dir):
    """The installed Snakemake's own log of a failed ``--keep-going`` run."""
    import subprocess
    import sys

    pytest.importorskip("snakemake")
    (run_dir / "Snakefile").write_text('''
rule all:
    input:
        expand("work/demo/cache/{block}.done", block=["good", "broken"]),


rule split_block:
    output:
        "work/{zone}/cache/{block}.done",
    log:
        "work/{zone}/logs/split_block/{block}.log",
    shell:
        """
        echo "2026-11-23 21:06:21,100 INFO towerpipe: job split_block" > {log}
        if [ {wildcards.block} = broken ]; then
          echo "2026-11-23 21:06:21,200 ERROR towerpipe: InputError: {wildcards.block}.laz: truncated" >> {log}
          exit 1
        fi
        touch {output}
        """
''')
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-c1", "--keep-going", "--nolock"],
        check=False,
        cwd=run_dir,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode != 0 and "Error in rule split_block" in proc.stderr, proc.stderr[-2000:]
    logs = sorted((run_dir / ".snakemake/log").glob("*.snakemake.log"))
    assert logs
    assert failures_from_log(logs, "work") == {"demo": {"broken": "split_block: InputError: broken.laz: truncated"}}


FAILED_BATCH = _failed(
    "products_batch",
    4,
    "work/demo/batches/b5000_57501/products",
    "work/demo/logs/products_batch/b5000_57501.log",
    "zone=demo, batch=b5000_57501",
    20,
)


def test_a_failed_batch_fails_each_of_its_blocks(run_dir):
    main = _write(run_dir / "smk.log", HEADER + FAILED_BATCH + FOOTER)
    _write(
        run_dir / "work/demo/logs/products_batch/b5000_57501.log",
        "2026-11-23 21:06:22,000 ERROR towerpipe: MemoryError: Unable to allocate 3.20 GiB\n",
    )
    reason = "products_batch: MemoryError: Unable to allocate 3.20 GiB (batch b5000_57501)"
    batches = {"demo": {"b5000_57500": ["a"], "b5000_57501": ["b", "c"]}}
    assert failures_from_log(main, "work", batches=batches) == {"demo": {"b": reason, "c": reason}}
    # without the zone's batches (no plan), the batch is named as it is
    assert failures_from_log(main, "work") == {"demo": {"b5000_57501": reason.removesuffix(" (batch b5000_57501)")}}


def test_a_failed_split_batch_fails_each_of_its_blocks(run_dir):
    failed = _failed(
        "split_batch",
        2,
        "work/demo/batches/b5000_57501/split",
        "work/demo/logs/split_batch/b5000_57501.log",
        "zone=demo, batch=b5000_57501",
        10,
    )
    main = _write(run_dir / "smk.log", HEADER + failed + FOOTER)
    _write(
        run_dir / "work/demo/logs/split_batch/b5000_57501.log",
        "2026-11-23 21:06:22,000 ERROR towerpipe: OSError: disk full\n",
    )
    reason = "split_batch: OSError: disk full (batch b5000_57501)"
    # the split batches are the headers'; the plan's batches do not name them
    split = {"demo": {"b5000_57501": ["b", "c"]}}
    plan = {"demo": {"b5000_57501": ["x"]}}
    assert failures_from_log(main, "work", batches=plan, split_batches=split) == {"demo": {"b": reason, "c": reason}}
