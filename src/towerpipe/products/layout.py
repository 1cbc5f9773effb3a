"""The layout of a zone's products, ``results/<zone>/``: defined here once.

The workflow links the per-block products into these places (``zone_products`` in
``workflow/rules/common.smk``), the zone assembly writes the zone-level files, and the
QA pages link to all of them with paths relative to each other.
"""

from __future__ import annotations

import posixpath

#: Per-block products, relative to ``results/<zone>/`` (``{block}`` is the block name).
BLOCK_LAZ = "blocks/{block}.laz"
BLOCK_GPKG = "towers/{block}.gpkg"
QA_PAGE = "qa/{block}.html"
QA_JSON = "qa/{block}.json"

#: Zone-level products.
ZONE_GPKG = "towers.gpkg"
QA_INDEX = "qa/index.html"
QA_INDEX_JSON = "qa/index.json"
#: Only in a zone published with failed blocks: which and why.
INCOMPLETE = "INCOMPLETE.txt"


def block_product(pattern: str, block: str) -> str:
    """``pattern`` (one of the ``BLOCK_*`` / ``QA_*`` constants) for ``block``."""
    return pattern.format(block=block)


def link(from_file: str, to_file: str) -> str:
    """Relative link from one product to another (both relative to ``results/<zone>/``)."""
    return posixpath.relpath(to_file, posixpath.dirname(from_file) or ".")
