"""Shared test fixtures and the paths of the real data sets (read from ../shared, never copied)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = (REPO.parent / "shared" / "data" / "real").resolve()
BACKGROUNDS = SHARED / "backgrounds"
TOWERS = SHARED / "towers"

#: Real IGN LiDAR HD tiles (Lambert-93), ground classified, no pylons.
RGBNIR_BLOCK = BACKGROUNDS / "ign_rgbnir_block.laz"  # 697,721 pts, pf 8, RGB+NIR, extra bytes
RGB_SUBSET = BACKGROUNDS / "ign_rgb_subset.laz"  # 70,840 pts, pf 8, NIR all zero
RGBNIR_SMALL = BACKGROUNDS / "ign_rgbnir_small.laz"  # 37,805 pts, pf 8
HIGH_NOISE = BACKGROUNDS / "ign_high_noise.laz"  # 50,233 pts, pf 6, ~27 points up to ~1,360 m up
BRIDGE = BACKGROUNDS / "ign_bridge.laz"  # 249,582 pts, pf 6
UAV_TOWERS = TOWERS / "uav_towers"
TS40K = TOWERS / "ts40k"
UTILITY_STRUCTURES = TOWERS / "utility_structures"


#: GDAL 3.6 (QGIS LTR of Debian 12), unpacked by scripts/gdal36_tools.sh (make setup).
GDAL36 = REPO / "build" / "gdal36"
GDAL36_OGRINFO = GDAL36 / "usr" / "bin" / "ogrinfo"
GDAL36_PYTHON = GDAL36 / "usr" / "lib" / "python3" / "dist-packages"
GDAL36_VALIDATOR = GDAL36_PYTHON / "osgeo_utils" / "samples" / "validate_gpkg.py"


def need(path: Path) -> Path:
    """Skip the test when a file of ../shared/data/real is absent."""
    if not path.exists():
        pytest.skip(f"{path} is absent (the real data lives in ../shared/data/real beside the repo)")
    return path


@pytest.fixture
def gdal36():
    """``run(*args)`` -> CompletedProcess of a GDAL 3.6 tool (``ogrinfo`` or ``validate_gpkg``)."""
    import os
    import subprocess

    if not (GDAL36_OGRINFO.exists() and GDAL36_VALIDATOR.exists()):
        pytest.skip(f"GDAL 3.6 is not unpacked in {GDAL36} (bash scripts/gdal36_tools.sh, Debian 12 only)")
    env = dict(os.environ, LD_LIBRARY_PATH=f"{GDAL36}/usr/lib/x86_64-linux-gnu:{GDAL36}/usr/lib",
               PYTHONPATH=str(GDAL36_PYTHON))

    def run(tool: str, *args: str) -> subprocess.CompletedProcess:
        cmd = [str(GDAL36_OGRINFO)] if tool == "ogrinfo" else ["python3", str(GDAL36_VALIDATOR)]
        return subprocess.run(cmd + list(args), capture_output=True, text=True, env=env)

    return run


@pytest.fixture
def pdal_cli():
    if shutil.which("pdal") is None:
        pytest.skip("the pdal CLI is not installed (bash scripts/install_pdal.sh)")
    return "pdal"


@pytest.fixture(scope="session")
def random_model_factory(tmp_path_factory):
    """``make(feature_set)`` -> a randomly initialised model bundle directory (plumbing tests)."""
    from towerpipe.features import FEATURE_SETS
    from towerpipe.model import PointNetClassifier, PointNetSegmenter, save_bundle
    from towerpipe.modelcard import code_version, config_hash

    made = {}

    def make(feature_set: str = "full") -> Path:
        if feature_set not in made:
            c = len(FEATURE_SETS[feature_set])
            card = {"name": f"towerpipe-random-{feature_set}", "version": "0", "bundle_version": 1,
                    "feature_set": feature_set, "features": FEATURE_SETS[feature_set], "normalisation": {},
                    "sampling": {"n_points": 2048}, "training_data": {"tiles": []},
                    "metrics": {"classifier": {}}, "code": code_version(), "config_hash": config_hash({})}
            out = tmp_path_factory.mktemp("model") / f"towerpipe-random-{feature_set}-v0"
            made[feature_set] = save_bundle(out, PointNetClassifier(c).eval(), PointNetSegmenter(c).eval(), card)
        return made[feature_set]

    return make
