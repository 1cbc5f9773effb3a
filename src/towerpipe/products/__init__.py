"""Products: the classified LAZ (merge), the GeoPackage, the zone layout and summary, and the QA pages."""
