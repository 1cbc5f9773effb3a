"""Preprocessing: splitting a block into its cache, ground, DTM and heights above ground (PDAL), tiling and attribute validity."""
