"""towerpipe: find and outline power transmission towers in airborne LiDAR.

The method is Carós et al. 2022 ("Object Segmentation of Cluttered Airborne
LiDAR Point Clouds"): 40 m windows of height-above-ground points, constrained
sampling, a light PointNet that gates windows and a second one that segments
the positive ones. The package holds all the logic; the Snakemake workflow in
``workflow/`` only calls into it.
"""

from towerpipe.errors import ConfigError, DiskSpaceError, InputError, ModelError, PdalError, TowerpipeError

__version__ = "0.44.0"

__all__ = [
    "__version__",
    "TowerpipeError",
    "ConfigError",
    "InputError",
    "PdalError",
    "DiskSpaceError",
    "ModelError",
]
