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


def real_tile_zone(
    seed: int,
    families: str | list[str],
    density: tuple[float, float],
    tile: str = "ign_rgbnir_block.laz",
    copies: int = 1,
    **over,
) -> dict:
    """The arguments of a zone of real tower families (one name or a list) on lines across copies of one real IGN tile."""
    return dict(
        seed=seed,
        real_backgrounds=BACKGROUNDS,
        background_files=[tile],
        copies=copies,
        lines=True,
        tower_source="real",
        real_towers=TOWERS,
        tower_families=[families] if isinstance(families, str) else list(families),
        tower_density=density,
        **over,
    )


def pytest_runtest_setup(item):
    """The one way a test skips without the real data: it is marked ``shared`` and ../shared is absent."""
    if item.get_closest_marker("shared") and not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent (the real data lives in ../shared/data/real beside the repo)")


@pytest.fixture
def gdal36():
    """``run(*args)`` -> CompletedProcess of a GDAL 3.6 tool (``ogrinfo`` or ``validate_gpkg``)."""
    import os
    import subprocess

    if not (GDAL36_OGRINFO.exists() and GDAL36_VALIDATOR.exists()):
        pytest.skip(f"GDAL 3.6 is not unpacked in {GDAL36} (bash scripts/gdal36_tools.sh, Debian 12 only)")
    env = dict(
        os.environ, LD_LIBRARY_PATH=f"{GDAL36}/usr/lib/x86_64-linux-gnu:{GDAL36}/usr/lib", PYTHONPATH=str(GDAL36_PYTHON)
    )

    def run(tool: str, *args: str) -> subprocess.CompletedProcess:
        cmd = [str(GDAL36_OGRINFO)] if tool == "ogrinfo" else ["python3", str(GDAL36_VALIDATOR)]
        return subprocess.run(cmd + list(args), capture_output=True, text=True, env=env)

    return run


@pytest.fixture
def pdal_cli():
    if shutil.which("pdal") is None:
        pytest.skip("the pdal CLI is not installed (bash scripts/install_pdal.sh)")
    return "pdal"


@pytest.fixture(scope="package")  # tests/ is no package: one per test run
def random_model_factory(tmp_path_factory):
    """``make(feature_set)`` -> a randomly initialised model bundle directory (plumbing tests)."""
    from towerpipe.model.bundle import save_bundle
    from towerpipe.model.cards import code_version, config_hash
    from towerpipe.model.features import FEATURE_SETS
    from towerpipe.model.pointnet import PointNetClassifier, PointNetSegmenter

    made = {}

    def make(feature_set: str = "full") -> Path:
        if feature_set not in made:
            c = len(FEATURE_SETS[feature_set])
            card = {
                "name": f"towerpipe-random-{feature_set}",
                "version": "0",
                "bundle_version": 1,
                "feature_set": feature_set,
                "features": FEATURE_SETS[feature_set],
                "normalisation": {},
                "sampling": {"n_points": 2048},
                "training_data": {"tiles": []},
                "metrics": {"classifier": {}},
                "code": code_version(),
                "config_hash": config_hash({}),
            }
            out = tmp_path_factory.mktemp("model") / f"towerpipe-random-{feature_set}-v0"
            made[feature_set] = save_bundle(out, PointNetClassifier(c).eval(), PointNetSegmenter(c).eval(), card)
        return made[feature_set]

    return make


#: The CI zone's scene (.test/config): 2 blocks of 120 m, 5 towers, one across the block edge.
CI_SYNTH = {"seed": 4242, "blocks": 2, "size": 120, "density": 8, "preset": "test", "edge_tower": True}
CI_BLOCKS = ("400000_4600000", "400120_4600000")


def snakemake_run(*args, env=None):
    """``python -m snakemake ARGS`` in the repository (no check)."""
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "snakemake", *args], cwd=REPO, capture_output=True, text=True, env=env)


def write_zone_config(path: Path, zones: dict, workdir: Path, **extra) -> Path:
    """A config file with ``zones`` and ``workdir`` (+ ``extra`` top-level sections)."""
    import yaml

    path.write_text(yaml.safe_dump({"zones": zones, "workdir": str(workdir), **extra}))
    return path


@pytest.fixture(scope="session")
def ci_scene(tmp_path_factory):
    """The CI zone's blocks, generated once per test run (the generator is deterministic)."""
    from towerpipe.synth import generate_zone

    out = tmp_path_factory.mktemp("ci_scene") / "in"
    generate_zone(out, **CI_SYNTH)
    return out


@pytest.fixture(scope="session")
def ci_reference(ci_scene, tmp_path_factory):
    """``results/<zone>/`` of a plain local run of the CI scene with the shipped model (a copy)."""
    import uuid

    tmp = tmp_path_factory.mktemp("ci_ref")
    zone = f"pytest_ref_{uuid.uuid4().hex[:6]}"
    cfg = write_zone_config(
        tmp / "c.yaml", {zone: {"input": str(ci_scene)}}, tmp / "work", preprocess={"tile_size": 120}
    )
    proc = snakemake_run("--cores", "2", f"results/{zone}/", f"--configfile={cfg}")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    ref = tmp / "results"
    shutil.copytree(REPO / "results" / zone, ref)
    shutil.rmtree(REPO / "results" / zone, ignore_errors=True)
    return ref


def tower_features(path, layer="towers"):
    """A zone's or block's towers without what names the run (zone, ids, files, time)."""
    import pyogrio

    df = pyogrio.read_dataframe(path, layer=layer)
    drop = [c for c in ("tower_id", "zone", "source_files", "processed_at", "first_seen") if c in df.columns]
    return df.drop(columns=drop).sort_values(["centroid_x", "centroid_y"]).reset_index(drop=True)


def same_points(a_path, b_path):
    """Every point record of two LAZ files is equal (their headers may differ)."""
    import laspy
    import numpy as np

    a, b = laspy.read(a_path), laspy.read(b_path)
    assert list(a.point_format.dimension_names) == list(b.point_format.dimension_names)
    np.testing.assert_array_equal(a.points.array, b.points.array)


#: The tower rules the tower tests start from (over the schema's defaults): towers from the
#: points at 0.5, no confident-core rule, no conductor rule.
LENIENT_TOWERS = {"threshold": 0.5, "min_core_prob": 0.0, "min_wire_support": 0.0}


def schema_config(**sections):
    """A validated config of one zone whose sections are ``sections`` (the schema fills in the rest)."""
    from towerpipe.config import SCHEMA_FILE, load_yaml, validate_config

    return validate_config({"zones": {"z": {"input": "in"}}, **sections}, load_yaml(REPO / SCHEMA_FILE, "schema"))


def section(cls, **values):
    """The typed section ``cls`` (a :class:`towerpipe.config.Section`) of a config whose section
    :attr:`~towerpipe.config.Section.SECTION` is ``values`` (the schema fills in the rest)."""
    return cls.from_config(schema_config(**{cls.SECTION: values}))


def tower_rules(**towers):
    """:class:`towerpipe.config.TowersConfig` over the schema's defaults."""
    from towerpipe.config import TowersConfig

    return section(TowersConfig, **towers)


def qa_limits(**overrides):
    """:class:`towerpipe.products.qa.metrics.Limits` of the schema's defaults, ``overrides``
    (any field, also the three that are tower rules) set over them."""
    from dataclasses import replace

    from towerpipe.products.qa.metrics import Limits

    return replace(Limits.from_config(schema_config()), **overrides)


#: The inference settings the inference tests start from (over the schema's defaults): the
#: paper's sliding grid, gate 0.5, one view, every window classified.
GRID_INFERENCE = {"windows": "grid", "gate": 0.5, "tta": 1, "min_height": None}


def tower_among_crowns(centre: tuple[float, float] = (50.0, 50.0), seed: int = 2):
    """``(n, 3)`` x, y, height of a 16 m lattice at ``centre`` with three 19 m crowns of 3 m
    radius 11 m away (woodland): within 7 m it is a height peak, within 10 m the crowns hide it."""
    import numpy as np

    rng = np.random.default_rng(seed)
    cx, cy = centre
    h = rng.uniform(0, 16, 250)
    tower = np.c_[cx + rng.uniform(-1.5, 1.5, 250) * (1 - h / 20), cy + rng.uniform(-1.5, 1.5, 250), h]
    crowns = []
    for dx, dy in ((11.0, 0.0), (-11.0, 0.0), (0.0, -11.0)):
        a, r = rng.uniform(0, 2 * np.pi, 300), 3.0 * np.sqrt(rng.uniform(0, 1, 300))
        crowns.append(np.c_[cx + dx + r * np.cos(a), cy + dy + r * np.sin(a), 19.0 - r - rng.uniform(0, 3, 300)])
    return np.concatenate([tower, *crowns])


def towers_side_by_side(centre: tuple[float, float] = (50.0, 50.0), seed: int = 4):
    """``(n, 3)`` x, y, height of two lattices of parallel lines 10.5 m apart: a 56 m one at
    ``centre`` whose crossarms (48-52 m) reach 9 m towards a 44 m one east of it, so that the
    lower tower's top lies under them (no height peak, even within 3 m); a conductor 30 m up
    and a 14 m flat roof 30 m away."""
    import numpy as np

    rng = np.random.default_rng(seed)
    cx, cy = centre
    parts = []
    for dx, top, n in ((0.0, 56.0, 900), (10.5, 44.0, 700)):
        h = rng.uniform(0.3, top, n)
        w = 3.5 * (1 - h / (1.2 * top))  # a body tapering to its top
        parts.append(np.c_[cx + dx + rng.uniform(-w, w), cy + rng.uniform(-w, w), h])
    arm = np.c_[cx + rng.uniform(-9, 9, 300), cy + rng.uniform(-0.5, 0.5, 300), rng.uniform(48, 52, 300)]
    s = np.linspace(-60, 60, 480)
    wire = np.c_[cx + 25 + 0 * s, cy + s, 30 + 0.001 * s**2]
    roof = np.c_[cx + rng.uniform(-40, -25, 400), cy + rng.uniform(20, 35, 400), np.full(400, 14.0)]
    return np.concatenate([*parts, arm, wire, roof])


def inference_settings(**inference):
    """:class:`towerpipe.config.InferenceConfig` over the schema's defaults."""
    from towerpipe.config import InferenceConfig

    return section(InferenceConfig, **inference)


def grid_inference(**inference):
    """:func:`inference_settings` over :data:`GRID_INFERENCE`."""
    return inference_settings(**{**GRID_INFERENCE, **inference})


def preprocess_settings(**preprocess):
    """:class:`towerpipe.config.PreprocessConfig` over the schema's defaults."""
    from towerpipe.config import PreprocessConfig

    return section(PreprocessConfig, **preprocess)


def extract(preds, block_name, block_bounds, *, point_threshold=None, **kw):
    """:func:`towerpipe.towers.extract.extract_towers` with :data:`LENIENT_TOWERS` rules: ``kw``
    naming a rule (a :class:`~towerpipe.config.TowersConfig` field) sets it, the rest is passed on."""
    from dataclasses import fields

    from towerpipe.config import TowersConfig
    from towerpipe.towers.extract import extract_towers

    names = {f.name for f in fields(TowersConfig)}
    rules = tower_rules(**{**LENIENT_TOWERS, **{k: v for k, v in kw.items() if k in names}})
    return extract_towers(
        preds,
        block_name,
        block_bounds,
        rules,
        point_threshold=point_threshold,
        **{k: v for k, v in kw.items() if k not in names},
    )


def write_pred(
    path: Path,
    block: str,
    point_index,
    prob,
    blocks: list[str] | None = None,
    block_id=None,
) -> Path:
    """A prediction file (:mod:`towerpipe.io.predictions`) holding ``prob`` for the points
    ``point_index`` of ``block`` (or, with ``block_id``, of ``blocks[block_id]`` row by row)."""
    import numpy as np

    from towerpipe.io.predictions import PRED_META_KEYS, save_pred

    blocks = blocks or [block]
    n = len(point_index)
    arrays = {
        "block_id": np.full(n, blocks.index(block), np.int32) if block_id is None else np.asarray(block_id, np.int32),
        "point_index": np.asarray(point_index, np.int64),
        "x": np.zeros(n),
        "y": np.zeros(n),
        "z": np.zeros(n),
        "hag": np.zeros(n, np.float32),
        "prob": np.asarray(prob, np.float32),
    }
    meta = {k: None for k in PRED_META_KEYS}
    meta.update(block=block, blocks=blocks, tile=Path(path).stem, zone="z")
    save_pred(path, arrays, meta)
    return Path(path)


def model_card(feature_set: str = "full") -> dict:
    """A minimal valid model card of ``feature_set`` (for bundles the tests write)."""
    from towerpipe.model.cards import code_version, config_hash
    from towerpipe.model.features import FEATURE_SETS

    return {
        "name": f"towerpipe-{feature_set}",
        "version": "1",
        "bundle_version": 1,
        "feature_set": feature_set,
        "features": FEATURE_SETS[feature_set],
        "normalisation": {"norm_radius_m": 57.45},
        "sampling": {"n_points": 2048},
        "training_data": {"tiles": []},
        "metrics": {"classifier": {}},
        "code": code_version(),
        "config_hash": config_hash({"a": 1}),
    }


def trained_like(model, seed: int = 0):
    """Perturb every parameter (T-Nets leave identity) and calibrate batch-norm statistics
    on random data, so the tests do not pass on a trivial initial state."""
    import torch

    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 0.05)
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.momentum = 1.0
        model.train()
        model(torch.randn(4, 512, model.hparams["in_channels"], generator=g))
    return model.eval()


def tower_returns(design: str, x: float, rot: float, seed: int, height: float | None = None, density: float = 10.0):
    """Airborne returns on one generated tower of ``design`` standing at (x, 0) on flat ground,
    ``height`` m high (default: the middle of the design's range): (xyz, hag)."""
    import numpy as np

    from towerpipe.synth.primitives import sample_segments
    from towerpipe.synth.towers import HEIGHTS, place_tower

    lo, hi = HEIGHTS[design]
    rng = np.random.default_rng(seed)
    tower = place_tower(1, design, x, 0.0, rot, height or (lo + hi) / 2, lambda gx, gy: np.zeros(len(gx)), rng)
    xyz, _ = sample_segments(tower.prim, density, rng, beam=0.12, vertical_factor=0.25)
    return xyz, xyz[:, 2].copy()
