"""Synthetic airborne LiDAR zones with transmission towers (demo zone, fixtures, training).

Public API
----------
generate_zone(out_dir, *, seed, blocks=4, size=250.0, density=10.0, crs="EPSG:25831", ...)
    Write adjoining LAZ blocks + ``towers_truth.gpkg`` and return a :class:`ZoneTruth`.
SceneParams, preset(name, **overrides), preset_names()
    Scene parameters and their presets.
Terrain.load(path)
    The generator's true terrain (``terrain.npz`` next to the blocks) for HAG.
"""

from towerpipe.synth.params import SceneParams, preset, preset_names
from towerpipe.synth.terrain import Terrain
from towerpipe.synth.truth import ZoneTruth
from towerpipe.synth.zone import generate_zone

__all__ = ["SceneParams", "Terrain", "ZoneTruth", "generate_zone", "preset", "preset_names"]
