"""Files: LAS/LAZ reading, the column, tile, prediction and member files, the block cache, the zone's input files and atomic writes."""
