"""The benchmarks' own logic: the projection of a night (towerpipe.bench.scale), the SLURM
benchmark's helpers (towerpipe.bench.slurm), the planning benchmark's zone."""

from __future__ import annotations

import pytest

from towerpipe.bench.scale import profile_packs, project

E2E = {  # a 1 km² block: 4 tile jobs + 9 others, 100 s of job time
    "stages": {
        "infer_tile": {"jobs": 4, "s": 70.0, "max_rss_mb": 700.0, "io_mb": 920.0},
        "other": {"jobs": 9, "s": 30.0, "max_rss_mb": 850.0, "io_mb": 80.0},
    }
}
BLOCKS = {"blocks": 50, "jobs": 350, "job_s_median": 1.0, "scheduler_s_per_job": 0.5}


def _project(block_m, **kw):
    return project(
        E2E, BLOCKS, area_km2=100.0, block_m=block_m, nodes=2, node_cores=10, max_jobs=200, submit_per_s=5.0, **kw
    )


def test_large_blocks_take_the_e2e_jobs_per_km2():
    r = _project(1000.0)
    assert r["blocks"] == pytest.approx(100) and r["jobs"] == pytest.approx(1300)
    # work without the start-up of its 13 jobs, then every job's start-up again
    assert r["core_h"] * 3600 == pytest.approx(100 * (100.0 - 13 * 1.0) + 1300 * 1.0)
    assert r["wall_h_2_cores"] * 3600 == pytest.approx((100 * 87.0 + 1300 * 1.5) / 2)
    assert r["peak_rss_mb_per_job"] == 850.0 and r["io_mb_per_block"] == pytest.approx(1000.0)


def test_small_blocks_pay_the_start_up_of_their_jobs():
    big, small = _project(1000.0), _project(250.0)
    assert small["blocks"] == pytest.approx(1600) and small["jobs"] == pytest.approx(1600 * 7)
    assert small["core_h"] > big["core_h"]  # same points, more jobs
    assert small["io_mb_per_block"] == pytest.approx(1000.0 / 16)


def test_a_cluster_is_bound_by_cores_or_by_submission():
    r = _project(1000.0)
    cores_s, submit_s = r["core_h"] * 3600 / 20, 1300 / 5.0
    assert r["wall_h_slurm"] * 3600 == pytest.approx(max(cores_s, submit_s))
    assert r["slurm_bound"] == ("submission" if submit_s > cores_s else "cores")


def test_a_slurm_job_pays_its_start_on_its_node():
    bare, started = _project(1000.0), _project(1000.0, slurm_start_s=6.0)
    assert started["slurm_jobs"] == bare["slurm_jobs"] == pytest.approx(1300)  # one SLURM job per rule job
    assert (started["slurm_core_h"] - bare["slurm_core_h"]) * 3600 == pytest.approx(1300 * 6.0)
    assert started["core_h"] == bare["core_h"]  # the work of the jobs is the same


def test_grouped_slurm_jobs_per_block():
    packs = {"split": 8, "tile": 4}
    # 1 km² blocks: four tiles (the e2e block's), so 1/8 of a split job, one tile job, one block job
    big = _project(1000.0, slurm_start_s=6.0, packs=packs)
    assert big["slurm_jobs"] == pytest.approx(100 * (1 / 8 + 4 / 4 + 1))
    # 250 m blocks: one tile each
    small = _project(250.0, slurm_start_s=6.0, packs=packs)
    assert small["slurm_jobs"] == pytest.approx(1600 * (1 / 8 + 1 / 4 + 1))
    assert small["slurm_core_h"] < _project(250.0, slurm_start_s=6.0)["slurm_core_h"]


def test_batched_small_blocks_on_slurm_group_only_their_splits():
    packs = {"split": 8, "tile": 4}
    batched = {"blocks": 50, "batches": 2, "jobs": 58, "job_s_median": 0.3, "scheduler_s_per_job": 0.5}
    r = project(
        E2E,
        batched,
        area_km2=1.0,
        block_m=16.0,
        nodes=2,
        node_cores=10,
        max_jobs=200,
        submit_per_s=5.0,
        slurm_start_s=6.0,
        packs=packs,
        batched=True,
    )
    blocks = 1e6 / 256
    assert r["batched"] and r["jobs"] == pytest.approx(blocks * 58 / 50)
    # a split job for 8 blocks; the batches' jobs (58 - 50 per 50 blocks) one each
    assert r["slurm_jobs"] == pytest.approx(blocks / 8 + blocks * 8 / 50)


def test_the_cluster_profile_packs_splits_and_tiles():
    assert profile_packs() == {"split": 8, "tile": 8}


def test_slurm_bench_reads_slurm_times_and_strips_the_groups(tmp_path):
    import yaml

    from towerpipe.bench.slurm import GROUP_KEYS, _seconds, profile_without_groups

    assert _seconds("00:00:07") == 7 and _seconds("1:02:03") == 3723 and _seconds("2-00:00:01") == 172801
    cfg = yaml.safe_load((profile_without_groups(tmp_path / "p") / "config.yaml").read_text())
    assert not set(GROUP_KEYS) & set(cfg) and cfg["executor"] == "slurm"


def test_plan_bench_copies_a_block_on_a_grid(tmp_path):
    """The planning benchmark's zone: copies of one block side by side, named by their corner."""
    import laspy
    import numpy as np

    from towerpipe.bench import make_block
    from towerpipe.bench.plan import copy_block

    block = make_block(tmp_path / "one", size=16.0, density=8.0, seed=3)
    paths = copy_block(block, tmp_path / "zone", 5, 16.0)
    one = laspy.read(block)
    assert [p.name for p in paths] == ["400000_4600000.laz", "400016_4600000.laz", "400032_4600000.laz",
                                       "400000_4600016.laz", "400016_4600016.laz"]  # fmt: skip
    for k, p in enumerate(paths):
        las = laspy.read(p)
        assert len(las.points) == len(one.points)
        shift = np.array([(k % 3) * 16.0, (k // 3) * 16.0])
        assert np.allclose(np.c_[las.x, las.y] - shift, np.c_[one.x, one.y])


@pytest.mark.shared
@pytest.mark.usefixtures("pdal_cli")
def test_infer_bench_runs_the_tile_jobs_inference_on_a_zones_tiles(tmp_path, capsys):
    """``bench infer`` reads a zone's tiles and runs their inference as the tile jobs do, with
    the zone's model choice; a working directory without tiles is refused with the fix."""
    import argparse
    import json

    from conftest import RGBNIR_SMALL, preprocess_settings
    from towerpipe.bench.infer import bench_infer
    from towerpipe.model.choice import write_choice
    from towerpipe.preprocess.split import split_block
    from towerpipe.preprocess.tile import preprocess_tile

    work, prep = tmp_path / "work" / "z", preprocess_settings(tile_size=100.0)
    args = argparse.Namespace(work=str(work), repeat=2, workdir=None, keep=False, json=str(tmp_path / "infer.json"))
    with pytest.raises(SystemExit, match="no tiles"):
        bench_infer(args)
    meta = split_block(RGBNIR_SMALL, work / "cache" / "b", block="b", zone="z", settings=prep)
    for t in meta["tiles"]:
        preprocess_tile("z", "b", t, {"b": work / "cache" / "b"}, work / "tiles" / "b" / f"{t}.npz", settings=prep)
    write_choice("shape", {"b": work / "cache" / "b"}, work / "model.json", zone="z", key="inference.model")
    assert bench_infer(args) == 0
    res = json.loads((tmp_path / "infer.json").read_text())
    assert res["tiles"] == len(meta["tiles"]) and len(res["infer_runs"]) == 2
    assert res["ratio"] == pytest.approx(res["infer_s"] / res["read_s"])
    assert "infer: " in capsys.readouterr().out


def test_gate_stats_count_a_window_two_tiles_see_once(tmp_path):
    """The e2e benchmark's gate figures: summed over the tiles, and each window of the block once
    (a window near a tile edge is in both tiles' prediction files)."""
    import numpy as np

    from towerpipe.bench import gate_stats
    from towerpipe.io.predictions import PRED_ARRAYS, save_pred

    def tile(name, xs, segmented, shape_gated):
        gates = {
            "x": xs,
            "y": [5.0] * len(xs),
            "shape": [0.5] * len(xs),
            "prob": [0.5] * len(xs),
            "segmented": segmented,
        }
        meta = {
            **dict.fromkeys(("zone", "block", "tile", "blocks", "crs_wkt", "core_bounds", "model", "combine")),
            **dict.fromkeys(("gate_threshold", "points_core", "points_model_input_core", "peak_rss_mb"), 0),
            "timings": {},
            "windows_total": len(xs),
            "windows_shape_gated": shape_gated,
            "windows_passed_gate": sum(segmented),
            "windows_segmented": sum(segmented),
            "window_gates": gates,
        }
        save_pred(tmp_path / "pred" / "b" / f"{name}.npz", {k: np.zeros(0, d) for k, d in PRED_ARRAYS.items()}, meta)

    # the window at x = 50 straddles the two tiles' edge: segmented by both
    tile("0_0", [10.0, 30.0, 50.0], [False, False, True], 2)
    tile("1_0", [50.0, 70.0, 90.0, 110.0], [True, True, False, False], 2)
    g = gate_stats(tmp_path)
    assert (g["windows_total"], g["windows_segmented"], g["windows_shape_gated"]) == (7, 3, 4)
    assert (g["windows_distinct"], g["windows_segmented_distinct"]) == (6, 2)


@pytest.mark.parametrize(
    "argv, usage",
    [
        (["scale", "--help"], "usage: python -m towerpipe.bench scale "),
        (["--help"], "usage: python -m towerpipe.bench [-h] BENCH"),
    ],
)
def test_the_usage_reads_as_the_command_is_typed(argv, usage, capsys):
    from towerpipe.bench import main

    with pytest.raises(SystemExit):
        main(argv)
    assert capsys.readouterr().out.startswith(usage)
