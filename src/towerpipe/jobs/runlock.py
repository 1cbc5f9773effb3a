"""One run per zone: the run lock every entry point takes.

A run that executes jobs (``snakemake``, ``scripts/nightly.sh``, any wrapper: they all
go through the Snakefile) holds, until it exits,

* a shared lock on ``.snakemake/towerpipe/runs.lock`` (some run is alive), and
* an exclusive lock on ``.snakemake/towerpipe/zone-<zone>.lock`` for each zone it
  builds: a second run of the same zone stops before any job with a one-line error
  naming the live process.

The locks are ``flock(2)`` locks: the kernel drops them when the process dies, ``kill
-9`` included, so a lock can never be stale. Snakemake's own lock (``.snakemake/locks``)
has no owner and survives a killed run; ``snakemake --unlock`` clears it for every zone
at once, so it is only safe when no run is alive: :func:`runs_alive` (command line:
``python -m towerpipe.jobs.runlock idle``, exit 0 when no run is alive) tells.
"""

from __future__ import annotations

import fcntl
import os
import sys
from pathlib import Path

from towerpipe.errors import TowerpipeError

#: Where the lock files live, relative to the directory Snakemake runs in.
LOCK_DIR = Path(".snakemake") / "towerpipe"
_RUNS = "runs.lock"
_held: dict[str, int] = {}


def _path(name: str, root: str | os.PathLike[str] = ".") -> Path:
    d = Path(root) / LOCK_DIR
    d.mkdir(parents=True, exist_ok=True)
    return d / name


def zone_lock_file(zone: str, root: str | os.PathLike[str] = ".") -> Path:
    return _path(f"zone-{zone}.lock", root)


def hold_zone(zone: str, root: str | os.PathLike[str] = ".") -> None:
    """Take (and keep, until the process exits) the run locks of ``zone``.

    Idempotent within a process.

    Raises
    ------
    TowerpipeError
        Another live process runs the zone.
    """
    key = str(Path(root).resolve() / zone)
    if key in _held:
        return
    if "runs" not in _held:
        fd = os.open(_path(_RUNS, root), os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_SH)  # waits only while an unlock is being done
        _held["runs"] = fd
    path = zone_lock_file(zone, root)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        owner = Path(path).read_text().strip() or "unknown"
        os.close(fd)
        raise TowerpipeError(
            f"zone {zone} is being processed by another run (process {owner}); nothing done: wait for it to finish"
        ) from None
    os.ftruncate(fd, 0)
    os.write(fd, str(os.getpid()).encode())
    _held[key] = fd


def zone_busy(zone: str, root: str | os.PathLike[str] = ".") -> bool:
    """Whether a live process holds the run lock of ``zone``."""
    return not _try(zone_lock_file(zone, root))


def runs_alive(root: str | os.PathLike[str] = ".") -> bool:
    """Whether any live towerpipe run holds its locks in ``root``."""
    return not _try(_path(_RUNS, root))


def _try(path: Path) -> bool:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)


def if_idle(command: list[str], root: str | os.PathLike[str] = ".") -> bool:
    """Run ``command`` (e.g. ``snakemake --unlock``) only when no run is alive, holding off
    new runs while it runs. Returns whether it ran (its failure raises)."""
    import subprocess

    fd = os.open(_path(_RUNS, root), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        return True
    finally:
        os.close(fd)


USAGE = """usage: python -m towerpipe.jobs.runlock COMMAND
  busy ZONE                exit 0 when a live run holds ZONE's lock, else 1
  idle                     exit 0 when no run is alive, else 1
  if-idle -- CMD [ARG...]  run CMD only when no run is alive (exit 0 either way)"""


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] == ["idle"]:
        return 1 if runs_alive() else 0
    if args[:1] == ["busy"] and len(args) == 2:
        return 0 if zone_busy(args[1]) else 1
    if args[:2] == ["if-idle", "--"] and len(args) > 2:
        if not if_idle(args[2:]):
            print("towerpipe: a run is alive: its lock is left alone", file=sys.stderr)
        return 0
    print(USAGE, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
