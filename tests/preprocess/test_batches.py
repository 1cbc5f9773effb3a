"""towerpipe.preprocess.batches: which blocks of a zone run together, and in which batches."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import section
from towerpipe.preprocess.batches import BatchConfig, batch_blocks, batch_neighbours, morton, split_batches
from towerpipe.preprocess.tiling import plan_zone


def limits(**kw):
    return section(BatchConfig, **kw)


def grid(n_side, size=16.0, points=2_000, tiles=("0_0",)):
    """Plans of ``n_side`` × ``n_side`` blocks of ``size`` m (as plan_zone gives them)."""
    out = {}
    for i in range(n_side):
        for j in range(n_side):
            x, y = 400_000 + i * size, 4_600_000 + j * size
            out[f"{int(x)}_{int(y)}"] = {"bounds": [x, y, x + size, y + size], "tiles": list(tiles), "points": points}
    return out


def test_morton_interleaves_the_bits():
    ix, iy = np.array([0, 1, 0, 1, 2, 3, 0]), np.array([0, 0, 1, 1, 0, 0, 2])
    np.testing.assert_array_equal(morton(ix, iy), [0, 1, 2, 3, 4, 5, 8])


def test_a_grid_of_small_blocks_in_square_batches():
    blocks = grid(8)  # 16 m blocks from (400,000, 4,600,000): cells of 4 × 4 blocks, 64 m
    found = batch_blocks(blocks, limits(blocks=16))
    assert sorted(found) == ["b6250_71875", "b6250_71876", "b6251_71875", "b6251_71876"]
    assert sorted(b for bs in found.values() for b in bs) == sorted(blocks)
    for bs in found.values():  # each a quadrant
        xs = {blocks[b]["bounds"][0] for b in bs}
        ys = {blocks[b]["bounds"][1] for b in bs}
        assert len(bs) == 16 and len(xs) == 4 and len(ys) == 4


def test_a_block_added_later_changes_only_its_own_batch():
    blocks = grid(8)
    before = batch_blocks(blocks, limits(blocks=16))
    x, y = 400_000 + 8 * 16.0, 4_600_000.0  # a ninth column
    blocks["new"] = {"bounds": [x, y, x + 16, y + 16], "tiles": ["0_0"], "points": 2_000}
    after = batch_blocks(blocks, limits(blocks=16))
    assert {k: v for k, v in after.items() if k in before} == before
    assert [v for k, v in after.items() if k not in before] == [["new"]]


def test_a_cell_of_too_many_points_is_cut_into_even_runs():
    blocks = grid(7)  # cells of 5 × 5 blocks: 25, 10, 10 and 4 blocks of 2,000 points
    assert sorted(len(bs) for bs in batch_blocks(blocks, limits(blocks=25)).values()) == [4, 10, 10, 25]
    found = batch_blocks(blocks, limits(blocks=25, points=20_000))
    assert sorted(len(bs) for bs in found.values()) == [4, 8, 8, 9, 10, 10]
    assert {k for k, bs in found.items() if len(bs) in (8, 9)} == {"b5000_57500_0", "b5000_57500_1", "b5000_57500_2"}


@pytest.mark.parametrize(
    "change, why",
    [
        ({"tiles": ["0_0", "1_0"]}, "a block of two tiles"),
        ({"points": 60_000}, "a block larger than block_points"),
    ],
)
def test_a_zone_with_one_large_block_is_not_batched(change, why):
    blocks = grid(4)
    blocks[next(iter(blocks))].update(change)
    assert batch_blocks(blocks, limits()) == {}, why


def test_off_or_nothing_to_group():
    assert batch_blocks(grid(4), limits(block_points=0)) == {}
    assert batch_blocks(grid(1), limits()) == {}
    assert batch_blocks(grid(3), limits(points=2_000)) == {}  # one block a batch: no batch


def test_a_block_that_could_not_be_split_is_in_no_batch():
    blocks = grid(3)
    failed = next(iter(blocks))
    blocks[failed] = {"bounds": None, "tiles": [], "points": 0}
    found = batch_blocks(blocks, limits())
    assert sorted(b for bs in found.values() for b in bs) == sorted(set(blocks) - {failed})


def test_the_plan_names_each_block_batch_and_the_batches_neighbours():
    metas = {b: {"bounds": m["bounds"], "tiles": m["tiles"], "points": m["points"]} for b, m in grid(8).items()}
    metas["broken"] = {"error": "not a LAS/LAZ file", "header_bounds": None}
    plan = plan_zone(metas, 500.0, 40.0, limits(blocks=16))
    assert len(plan["batches"]) == 4
    for batch, bs in plan["batches"].items():
        assert all(plan["blocks"][b]["batch"] == batch for b in bs)
    assert plan["blocks"]["broken"]["batch"] is None
    # 16 m blocks within 40 m of each other: every quadrant borders the three others
    first, *others = sorted(plan["batches"])
    assert batch_neighbours(plan["batches"][first], plan["blocks"]) == others
    # without limits (a zone that is only prepared): no batch
    unbatched = plan_zone(metas, 500.0, 40.0)
    assert unbatched["batches"] == {} and all(p["batch"] is None for p in unbatched["blocks"].values())


def headers(blocks):
    """The header records of planned blocks (towerpipe.io.inputs: ``bounds``, ``point_count``)."""
    return {b: {"bounds": m["bounds"], "point_count": m["points"], "crs_wkt": None} for b, m in blocks.items()}


def test_the_splits_are_batched_by_the_headers_on_the_plans_grid():
    blocks = grid(8)
    assert split_batches(headers(blocks), limits(blocks=16)) == batch_blocks(blocks, limits(blocks=16))
    # a block of two tiles is still a small split
    blocks[next(iter(blocks))]["tiles"] = ["0_0", "1_0"]
    assert split_batches(headers(blocks), limits(blocks=16)) != {}


def test_an_unreadable_or_empty_header_splits_alone():
    found = headers(grid(3))
    unreadable, empty = sorted(found)[:2]
    found[unreadable] = None
    found[empty]["point_count"] = 0
    batched = {b for bs in split_batches(found, limits()).values() for b in bs}
    assert batched == set(found) - {unreadable, empty}


def test_a_large_header_or_off_splits_every_block_alone():
    found = headers(grid(3))
    assert split_batches(found, limits(block_points=0)) == {}
    found[next(iter(found))]["point_count"] = 60_000
    assert split_batches(found, limits()) == {}
