"""The default QGIS styles of the tower GeoPackage's layers: symbols, labels and map tips.

Each :class:`LayerStyle` (:data:`TOWERS`, :data:`TOWER_POINTS`, :data:`LINES`, :data:`SPANS`,
:data:`VANISHED`, :data:`CONDUCTORS`) says how one layer is drawn; :func:`qml` makes it the
QML text QGIS stores in a GeoPackage's ``layer_styles`` table, from the template
``towerpipe/data/towers.qml``. Which layer gets which style: :mod:`towerpipe.products.gpkg`.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources

from towerpipe.io.fields import Field

__all__ = ["LayerStyle", "TOWERS", "TOWER_POINTS", "LINES", "SPANS", "VANISHED", "CONDUCTORS", "qml"]


@dataclass(frozen=True)
class LayerStyle:
    """How a layer is drawn in QGIS.

    Attributes
    ----------
    symbol
        ``(kind, fill/line colour, outline colour, width)``; kind ``"fill"``, ``"marker"``
        or ``"line"``.
    placement
        QGIS label placement code.
    label
        Label expression (``None``: no labels).
    tip
        Map tip (HTML with QGIS expressions).
    """

    symbol: tuple[str, str, str | None, str]
    placement: str
    label: str | None
    tip: str


_TOWER_TIP = (
    '<b>[% "tower_id" %]</b><br>height [% format_number("height_m", 1) %] m, base '
    '[% format_number("base_z", 1) %] m<br>[% "n_points" %] points, mean probability '
    '[% format_number("prob_mean", 2) %], conductor support [% format_number("wire_support", 2) %]'
    '<br>shape score [% format_number("shape_score", 3) %] ([% "shape_view" %])'
    '<br>line [% "line_id" %] #[% "line_seq" %], review: [% "review_status" %]'
    '<br>block [% "block" %] ([% "blocks" %])'
)
#: Tower footprints.
TOWERS = LayerStyle(
    ("fill", "227,26,28,80", "165,15,21,255", "0.6"),
    "1",
    "concat(\"tower_id\", '\\n', format_number(\"height_m\", 1), ' m')",
    _TOWER_TIP,
)
#: Tower centroids.
TOWER_POINTS = LayerStyle(
    ("marker", "227,26,28,255", "103,0,13,255", "0.3"),
    "0",
    "concat(\"tower_id\", '\\n', format_number(\"height_m\", 1), ' m')",
    _TOWER_TIP,
)
#: Power lines.
LINES = LayerStyle(
    ("line", "31,120,180,255", None, "0.8"),
    "2",
    "concat('line ', \"line_id\", ' (', \"tower_count\", ' towers)')",
    '<b>line [% "line_id" %]</b><br>[% "tower_count" %] towers, [% format_number("length_m", 0) %] m',
)
#: Tower-to-tower spans.
SPANS = LayerStyle(
    ("line", "166,206,227,255", None, "0.4"),
    "2",
    "concat(format_number(\"length_m\", 0), ' m')",
    '<b>span [% "from_tower" %] → [% "to_tower" %]</b><br>[% format_number("length_m", 1) %] m, '
    'bearing [% format_number("bearing_deg", 1) %]°, [% "conductor_points" %] conductor '
    'points<br>lowest conductor [% format_number("lowest_conductor_m", 1) %] m above ground, '
    'clearance to vegetation [% format_number("clearance_m", 1) %] m',
)
#: Vanished towers (grey).
VANISHED = LayerStyle(
    ("fill", "150,150,150,60", "90,90,90,255", "0.5"),
    "1",
    "concat(\"tower_id\", ' (vanished)')",
    '<b>[% "tower_id" %]</b> not found since [% "vanished_since" %]<br>last seen '
    '[% "last_seen" %] in block [% "block" %], review: [% "review_status" %]',
)
#: Conductor points (no labels).
CONDUCTORS = LayerStyle(
    ("marker", "31,120,180,255", "31,120,180,255", "0.0"),
    "0",
    None,
    'conductor point, [% format_number("hag", 1) %] m above ground',
)

_GEOMETRY_CODE = {"marker": "0", "line": "1", "fill": "2"}


def _symbol_xml(kind: str, color: str, outline: str | None, width: str) -> ET.Element:
    opts = {
        "fill": [
            ("color", color),
            ("outline_color", outline),
            ("outline_style", "solid"),
            ("outline_width", width),
            ("outline_width_unit", "MM"),
            ("style", "solid"),
            ("joinstyle", "miter"),
        ],
        "marker": [
            ("name", "triangle" if outline != color else "circle"),
            ("color", color),
            ("outline_color", outline),
            ("outline_width", width),
            ("outline_width_unit", "MM"),
            ("size", "3.2" if outline != color else "1.0"),
            ("size_unit", "MM"),
        ],
        "line": [
            ("line_color", color),
            ("line_width", width),
            ("line_width_unit", "MM"),
            ("line_style", "solid"),
            ("capstyle", "round"),
            ("joinstyle", "round"),
        ],
    }[kind]
    cls = {"fill": "SimpleFill", "marker": "SimpleMarker", "line": "SimpleLine"}[kind]
    sym = ET.Element("symbol", {"type": kind, "name": "0", "alpha": "1", "clip_to_extent": "1", "force_rhr": "0"})
    layer = ET.SubElement(sym, "layer", {"class": cls, "enabled": "1", "locked": "0", "pass": "0"})
    opt = ET.SubElement(layer, "Option", {"type": "Map"})
    for name, value in opts:
        ET.SubElement(opt, "Option", {"name": name, "type": "QString", "value": value})
    return sym


def qml(style: LayerStyle, fields: Mapping[str, Field]) -> str:
    """The QML text of a layer drawn with ``style``.

    Parameters
    ----------
    style
        How the layer is drawn.
    fields
        The layer's fields: their titles become the field aliases.
    """
    text = resources.files("towerpipe").joinpath("data/towers.qml").read_text(encoding="utf-8")
    head, body = text.split("<qgis ", 1)
    root = ET.fromstring("<qgis " + body)
    symbols = root.find("renderer-v2/symbols")
    for old in list(symbols):
        symbols.remove(old)
    symbols.append(_symbol_xml(*style.symbol))
    labeling = root.find("labeling")
    if style.label is None:
        root.remove(labeling)
        root.set("labelsEnabled", "0")
    else:
        labeling.find("settings/text-style").set("fieldName", style.label)
        labeling.find("settings/placement").set("placement", style.placement)
    aliases = root.find("aliases")
    for old in list(aliases):
        aliases.remove(old)
    for i, (name, f) in enumerate([("fid", None), *fields.items()]):
        ET.SubElement(aliases, "alias", {"field": name, "index": str(i), "name": f.title if f else ""})
    root.find("mapTip").text = style.tip
    root.find("previewExpression").text = (
        '"tower_id"' if "tower_id" in fields else ('"line_id"' if "line_id" in fields else '"fid"')
    )
    root.find("layerGeometryType").text = _GEOMETRY_CODE[style.symbol[0]]
    ET.indent(root)
    doctype = head.split("\n", 1)[0]
    return f"{doctype}\n{ET.tostring(root, encoding='unicode')}\n"
