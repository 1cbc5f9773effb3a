"""``towerpipe lines``: the lines through several published zones, written to one GeoPackage.

The lines themselves are :func:`towerpipe.towers.lines.build_lines`; here the zones' per-block
GeoPackages are assembled as a zone's are (:func:`towerpipe.jobs.zone.zone_towers`) and written.
"""

from __future__ import annotations

import json
from datetime import UTC
from pathlib import Path
from typing import Any

__all__ = ["lines_across_zones"]


def lines_across_zones(zone_dirs: list[str | Path], out_path: str | Path) -> dict[str, int]:
    """Lines through several zones: a line leaving one zone goes on in the next.

    Reads each published zone directory's per-block GeoPackages (``towers/<block>.gpkg``:
    towers and conductor points) and builds the lines of all of them at once. Tower ids
    are the zones' own (they are made from positions, the same in every zone of one CRS);
    a tower reported by two zones (overlapping footprints) is kept once, from the first
    zone given.

    Parameters
    ----------
    zone_dirs
        ``results/<zone>`` directories, all in one CRS.
    out_path
        GeoPackage to write: layers ``towers``, ``tower_points``, ``lines``, ``spans``.

    Returns
    -------
    dict
        ``towers``, ``lines``, ``spans`` counts.
    """
    from datetime import datetime

    from towerpipe.errors import InputError
    from towerpipe.jobs.zone import write_zone_gpkg, zone_towers
    from towerpipe.towers.registry import empty_registry

    gpkgs = []
    for d in zone_dirs:
        found = sorted(Path(d, "towers").glob("*.gpkg"))
        if not found:
            raise InputError(d, "holds no towers/<block>.gpkg: give published zone directories (results/<zone>)")
        gpkgs += found
    content = zone_towers(gpkgs, registry=empty_registry(), run_time=datetime.now(UTC))
    write_zone_gpkg(
        out_path,
        content,
        {"zones": json.dumps([str(d) for d in zone_dirs]), **content["metadata"]},
        vanished=False,
    )
    return {k: 0 if content[k] is None else len(content[k]) for k in ("towers", "lines", "spans")}


def register(sub: Any) -> None:
    """``towerpipe lines``: the lines through several zones."""
    p = sub.add_parser("lines", help="link the towers of several zones into lines (a line across zone borders)")
    p.add_argument("zones", nargs="+", help="published zone directories (results/<zone>), one CRS")
    p.add_argument("-o", "--out", required=True, help="GeoPackage to write (towers, tower_points, lines, spans)")
    p.set_defaults(func=_cli)


def _cli(args: Any) -> int:
    counts = lines_across_zones(args.zones, args.out)
    print(f"{args.out}: {counts['towers']} towers, {counts['lines']} lines, {counts['spans']} spans")
    return 0
