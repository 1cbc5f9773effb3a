"""Inference: the windows of a tile (candidates or grid) and the gated classify-then-segment pass."""
