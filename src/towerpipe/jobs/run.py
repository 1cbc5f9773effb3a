"""``towerpipe run ZONE``: process a zone through the workflow, with one-line errors.

A front end over Snakemake's Python API (``snakemake.api``) for operators::

    towerpipe run zone2 --config my.yaml --cores 4 [--dry-run]

is ``snakemake --cores 4 --keep-going results/zone2/ --configfile=my.yaml`` without the
``--configfile`` ordering trap (that option takes several files, so a target after it is
read as a config file). The config is loaded and checked before Snakemake starts: a
missing file, bad YAML, an unknown key or an unknown zone is one line. The workflow
profile (``workflow/profiles/default``, what ``snakemake`` applies to every run) is
applied the same way. ``snakemake ...`` keeps working as before.
"""

from __future__ import annotations

import argparse
import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from towerpipe.config import SCHEMA_FILE, effective_config, load_yaml
from towerpipe.errors import ConfigError, TowerpipeError

log = logging.getLogger(__name__)

#: The workflow profile Snakemake applies to every run, relative to the repository root.
PROFILE = "workflow/profiles/default/config.yaml"
#: The workflow, relative to the repository root (where Snakemake finds it).
SNAKEFILE = "workflow/Snakefile"


def find_root(start: str | os.PathLike[str] | None = None) -> Path:
    """The towerpipe checkout to run in: the working directory when it holds the Snakefile,
    else the checkout this package was installed from (editable install)."""
    for cand in (Path(start or os.getcwd()), Path(__file__).resolve().parents[3]):
        if (cand / SNAKEFILE).is_file() and (cand / SCHEMA_FILE).is_file():
            return cand
    raise ConfigError("no towerpipe Snakefile here: run `towerpipe run` in the towerpipe directory")


def profile_settings(root: Path) -> dict[str, Any]:
    """The workflow profile's settings as keyword arguments of Snakemake's settings classes.

    Every key of the profile must be understood here, so that ``towerpipe run`` never
    silently differs from ``snakemake``.
    """
    from snakemake.settings.enums import RerunTrigger

    prof = load_yaml(root / PROFILE, "workflow profile")
    known = {
        "cores": ("resources", "cores", int),
        "rerun-incomplete": ("dag", "force_incomplete", bool),
        "rerun-triggers": ("dag", "rerun_triggers", lambda v: frozenset(RerunTrigger.parse_choice(t) for t in v)),
        "show-failed-logs": ("output", "show_failed_logs", bool),
        "printshellcmds": ("output", "printshellcmds", bool),
    }
    out: dict[str, dict[str, Any]] = {"resources": {}, "dag": {}, "output": {}}
    for key, value in prof.items():
        if key not in known:
            raise ConfigError(
                f"{root / PROFILE}: key {key!r} is not applied by `towerpipe run`; "
                f"add it to towerpipe.jobs.run.profile_settings"
            )
        group, name, conv = known[key]
        out[group][name] = conv(value)
    return out


def check_zone(config: Mapping[str, Any], zone: str) -> None:
    """The zone is configured and its input is there, with a block in it (or will be generated)."""
    from towerpipe.io.inputs import find_blocks, no_blocks_message

    zones = config.get("zones") or {}
    if zone not in zones:
        raise ConfigError(
            f"zone {zone!r} is not configured (known: {', '.join(sorted(zones))}); add "
            f"`zones: {{{zone}: {{input: DIR}}}}` to a YAML file and pass it with --config"
        )
    zc = zones[zone]
    if "synth" in zc:
        return
    if not Path(zc["input"]).is_dir():
        raise ConfigError(f"zones.{zone}.input: directory {zc['input']!r} does not exist")
    if not find_blocks(zc["input"]):
        raise ConfigError(no_blocks_message(zone, zc["input"]))


def run_zone(
    zone: str,
    configfile: str | os.PathLike[str] | None = None,
    *,
    cores: int | None = None,
    dry_run: bool = False,
    keep_going: bool = True,
    root: str | os.PathLike[str] | None = None,
) -> int:
    """Run (or plan, ``dry_run``) ``results/<zone>/``; returns the exit status.

    Raises
    ------
    ConfigError
        Before Snakemake starts: the config file is missing or invalid, the zone is not
        configured, or its input directory is missing or holds no .las/.laz file.
    """
    from snakemake.api import SnakemakeApi
    from snakemake.settings.types import (
        ConfigSettings,
        DAGSettings,
        ExecutionSettings,
        OutputSettings,
        ResourceSettings,
    )

    root = find_root(root)
    configfiles = [Path(configfile).resolve()] if configfile else []
    if configfile and not Path(configfile).is_file():
        raise ConfigError(f"--config {configfile}: no such file")
    config = effective_config(configfiles, root=root)  # what the workflow reads: config/models.yaml too
    check_zone(config, zone)
    prof = profile_settings(root)
    resources = dict(prof["resources"], **({"cores": cores} if cores else {}))
    target = f"results/{zone}/"
    cwd = os.getcwd()
    # Snakemake prints through its own handlers: not a second time through towerpipe's root handler
    logging.getLogger("snakemake").propagate = False
    try:
        with SnakemakeApi(OutputSettings(dryrun=dry_run, **prof["output"])) as api:
            workflow = api.workflow(
                resource_settings=ResourceSettings(**resources),
                config_settings=ConfigSettings(configfiles=configfiles),
                snakefile=root / SNAKEFILE,
                workdir=root,
            )
            dag = workflow.dag(DAGSettings(targets={target}, **prof["dag"]))
            dag.execute_workflow(
                executor="local",
                pseudo_executor="dryrun" if dry_run else None,
                execution_settings=ExecutionSettings(keep_going=keep_going),
            )
    except SystemExit as exc:  # the workflow's config checks print their one line and exit
        return int(exc.code) if isinstance(exc.code, int) else 1
    except TowerpipeError:
        raise
    except Exception as exc:  # noqa: BLE001 - Snakemake's errors, shown as one line
        print(f"towerpipe: run of zone {zone} failed: {error_line(exc)}", flush=True)
        return 1
    finally:
        os.chdir(cwd)
    return 0


def error_line(exc: BaseException) -> str:
    """The one line that says what an error of Snakemake is: its first line that says more than
    a label (Snakemake's ``WorkflowError`` reads "Error:", then the message on the next line)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    said = [ln for ln in lines if ln.rstrip(":").strip() not in ("Error", "WorkflowError", type(exc).__name__)]
    return said[0] if said else type(exc).__name__


def _cmd(args: argparse.Namespace) -> int:
    return run_zone(args.zone, args.config, cores=args.cores, dry_run=args.dry_run, keep_going=not args.stop_early)


def register(subparsers: Any) -> None:
    """Add ``towerpipe run``."""
    p = subparsers.add_parser(
        "run", help="process a zone (results/ZONE/) through the workflow", description=__doc__.split("\n\n")[1]
    )
    p.add_argument("zone", metavar="ZONE", help="a zone of the config (zones: ...)")
    p.add_argument("--config", metavar="FILE", help="YAML merged over config/config.yaml (e.g. your zones)")
    p.add_argument("--cores", type=int, metavar="N", help="CPU cores to use (default: the workflow profile's)")
    p.add_argument("-n", "--dry-run", action="store_true", help="list the jobs that would run, run nothing")
    p.add_argument(
        "--stop-early",
        action="store_true",
        help="stop at the first failed job (default: keep going, publish the zone INCOMPLETE)",
    )
    p.set_defaults(func=_cmd)
