"""Attribute schemas of the product layers: type, title, description and precision per field.

A layer's fields are declared once, as an ordered ``{name: Field}`` mapping next to the
concept that owns them (:data:`towerpipe.towers.records.TOWER_FIELDS`,
:data:`towerpipe.towers.lines.LINE_FIELDS`, …). The same declaration gives

* the column order and dtypes of the GeoDataFrames (:func:`empty_frame`, :func:`conform`);
* the rounding of every value written (``digits``: 2 decimals for lengths is 1 cm), so a
  GeoPackage holds ``34.67``, never the float32 noise ``34.669998``;
* the ``gpkg_data_columns`` rows (title and description with units) and the field
  aliases of the embedded QGIS style (:mod:`towerpipe.products.gpkg`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the frames' libraries load when a frame is built: declaring fields is free
    import geopandas as gpd
    import pandas as pd

#: pandas dtype of DATETIME fields (GeoPackage DATETIME: ISO 8601, UTC).
DATETIME = "datetime64[ms, UTC]"
#: Grid (CRS units, m) the vertices of written geometries are snapped to: 1 cm.
GEOMETRY_GRID = 0.01


@dataclass(frozen=True)
class Field:
    """One attribute of a product layer.

    Attributes
    ----------
    dtype
        ``"str"``, ``"int64"``, ``"Int64"`` (integer that may be NULL), ``"float64"``,
        ``"bool"`` or :data:`DATETIME`.
    title
        Short human title with the unit, e.g. ``"Height (m)"`` (QGIS alias).
    description
        What the value is and how it was measured (``gpkg_data_columns.description``).
    digits
        Decimals kept for ``float64`` values (``None``: all).
    enum
        Allowed values of a text field (a ``gpkg_data_column_constraints`` enum).
    """

    dtype: str
    title: str
    description: str
    digits: int | None = None
    enum: tuple[str, ...] | None = None


def dtypes(fields: Mapping[str, Field]) -> dict[str, str]:
    """``{name: dtype}`` of a schema."""
    return {k: f.dtype for k, f in fields.items()}


def _empty(dtype: str) -> pd.Series:
    import pandas as pd

    return pd.Series([], dtype=object if dtype == "str" else dtype)


def empty_frame(fields: Mapping[str, Field], crs: Any = None, geometry: bool = True) -> gpd.GeoDataFrame | pd.DataFrame:
    """An empty table with the schema's columns and dtypes (and a geometry column)."""
    import geopandas as gpd
    import pandas as pd

    data = {k: _empty(f.dtype) for k, f in fields.items()}
    if not geometry:
        return pd.DataFrame(data)
    return gpd.GeoDataFrame(data, geometry=gpd.GeoSeries([], crs=crs), crs=crs)


def _cast(values: pd.Series, field: Field) -> pd.Series:
    import pandas as pd

    if field.dtype == "str":
        return values.astype(object).where(values.notna(), None)
    if field.dtype == DATETIME:
        return pd.to_datetime(values, utc=True).astype(DATETIME)
    if field.dtype == "float64":
        out = pd.to_numeric(values, errors="raise").astype("float64")
        return out.round(field.digits) if field.digits is not None else out
    return values.astype(field.dtype)


def conform(frame: pd.DataFrame, fields: Mapping[str, Field], crs: Any = None) -> gpd.GeoDataFrame | pd.DataFrame:
    """``frame`` with exactly the schema's columns, in order, cast and rounded.

    Geometries (when ``frame`` has them) are snapped to :data:`GEOMETRY_GRID` and
    stay valid. Raises ``ValueError`` naming the missing columns.
    """
    import geopandas as gpd
    import pandas as pd
    import shapely

    missing = [c for c in fields if c not in frame.columns]
    if missing:
        raise ValueError(f"table lacks columns {missing}")
    out = pd.DataFrame({k: _cast(frame[k].reset_index(drop=True), f) for k, f in fields.items()})
    if not isinstance(frame, gpd.GeoDataFrame):
        return out
    crs = crs if crs is not None else frame.crs
    geoms = np.asarray(frame.geometry.values, dtype=object)
    if len(geoms):
        geoms = shapely.set_precision(geoms, GEOMETRY_GRID)
    return gpd.GeoDataFrame(out, geometry=gpd.GeoSeries(geoms, crs=crs), crs=crs)


def join_values(values: Sequence[str]) -> str:
    """Several values in one text field: ``"a;b"`` (the one separator of every product)."""
    return SEPARATOR.join(str(v) for v in values)


#: Separator of multi-valued text fields (blocks, source files).
SEPARATOR = ";"
