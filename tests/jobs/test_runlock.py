"""One run per zone (towerpipe.jobs.runlock) and the nightly script's guards."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from conftest import REPO, snakemake_run, write_zone_config


def _holder(tmp_path, zone):
    """A live process holding ``zone``'s run lock in ``tmp_path`` (as a running Snakemake does)."""
    code = (
        "import sys, time; from towerpipe.jobs.runlock import hold_zone; "
        f"hold_zone({zone!r}, {str(tmp_path)!r}); print('held', flush=True); time.sleep(60)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_second_run_of_a_zone_is_refused_naming_the_live_process(tmp_path):
    from towerpipe.errors import TowerpipeError
    from towerpipe.jobs.runlock import hold_zone, runs_alive, zone_busy

    assert not runs_alive(tmp_path) and not zone_busy("z1", tmp_path)
    proc = _holder(tmp_path, "z1")
    try:
        assert zone_busy("z1", tmp_path) and runs_alive(tmp_path) and not zone_busy("z2", tmp_path)
        code = f"from towerpipe.jobs.runlock import hold_zone; hold_zone('z1', {str(tmp_path)!r})"
        other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert other.returncode != 0
        assert f"zone z1 is being processed by another run (process {proc.pid})" in other.stderr
        hold_zone("z2", tmp_path)  # another zone runs beside it
    finally:
        proc.kill()
        proc.wait()
    # kill -9 releases it: no stale lock
    assert not zone_busy("z1", tmp_path)
    try:
        hold_zone("z1", tmp_path)
    except TowerpipeError as exc:  # pragma: no cover - the assertion below explains
        raise AssertionError(f"the lock of a killed run survived: {exc}") from exc


def test_a_plain_snakemake_on_a_busy_zone_stops_with_one_line(tmp_path):
    """Snakemake itself (not only the nightly script): exit 75, the live process named, no traceback."""
    zone = f"pytest_busy_{os.getpid()}"
    (tmp_path / "in").mkdir()
    cfg = write_zone_config(tmp_path / "c.yaml", {zone: {"input": str(tmp_path / "in")}}, tmp_path / "work")
    proc = _holder(REPO, zone)
    try:
        run = snakemake_run("--cores", "1", f"results/{zone}/", f"--configfile={cfg}")
    finally:
        proc.kill()
        proc.wait()
        for p in (REPO / ".snakemake" / "towerpipe").glob(f"zone-{zone}*.lock"):
            p.unlink()
    assert run.returncode == 75, run.stderr
    assert run.stderr.rstrip().splitlines()[-1] == (
        f"zone {zone} is being processed by another run (process {proc.pid}); nothing done: wait for it to finish"
    )
    assert "Traceback" not in run.stderr and "Exception" not in run.stderr


def test_unlock_only_when_no_run_is_alive(tmp_path):
    marker = tmp_path / "unlocked"
    cmd = [sys.executable, "-m", "towerpipe.jobs.runlock", "if-idle", "--", "touch", str(marker)]
    proc = _holder(tmp_path, "z1")
    try:
        subprocess.run(cmd, cwd=tmp_path, check=True)
        assert not marker.exists()  # a live run: Snakemake's lock is left alone
    finally:
        proc.kill()
        proc.wait()
    subprocess.run(cmd, cwd=tmp_path, check=True)
    assert marker.exists()


def test_nightly_exits_75_while_the_zone_runs_and_never_unlocks_a_live_run(tmp_path):
    # the nightly script runs in the repository: hold the zone's lock there
    zone = f"pytest_lock_{os.getpid()}"
    proc = _holder(REPO, zone)
    fake = tmp_path / "snakemake"  # stands for Snakemake: exits 9
    fake.write_text("#!/bin/sh\nexit 9\n")
    fake.chmod(0o755)
    env = dict(os.environ, SNAKEMAKE=str(fake), PYTHON=sys.executable)
    try:
        t0 = time.monotonic()
        run = subprocess.run(["bash", "scripts/nightly.sh", zone], cwd=REPO, env=env, capture_output=True, text=True)
        assert run.returncode == 75, run.stderr
        assert "another run of zone" in run.stderr and time.monotonic() - t0 < 30
        # another zone: its run starts, but Snakemake's lock (shared by all zones) is not cleared
        run = subprocess.run(
            ["bash", "scripts/nightly.sh", zone + "_other"], cwd=REPO, env=env, capture_output=True, text=True
        )
        assert "a run is alive: its lock is left alone" in run.stderr and run.returncode == 9
    finally:
        proc.kill()
        proc.wait()
        for p in (REPO / ".snakemake" / "towerpipe").glob(f"zone-{zone}*.lock"):
            p.unlink()
