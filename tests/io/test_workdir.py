"""towerpipe.io.workdir: a zone's last run found whether its blocks ran one by one or in batches."""

from __future__ import annotations

from towerpipe.io import workdir


def _touch(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"")
    return path


def test_zone_files_of_blocks_and_of_batches(tmp_path):
    z = tmp_path / "z"
    own = _touch(z / workdir.PRED.format(block="c", tile="0_0"))
    in_batch = [
        _touch(z / workdir.BATCH_INFER.format(batch="b3333_38333") / workdir.PRED.format(block=b, tile="0_0"))
        for b in ("a", "b")
    ]
    _touch(z / workdir.BATCH_INFER.format(batch="b3333_38333") / workdir.TILE.format(block="a", tile="0_0"))
    gpkg = _touch(z / workdir.BATCH_PRODUCTS.format(batch="b3333_38333") / workdir.TOWERS_GPKG.format(block="a"))
    # sorted by block, then tile, wherever each is
    assert workdir.zone_files(tmp_path, "z", workdir.PRED) == [*in_batch, own]
    assert workdir.zone_files(tmp_path, "z", workdir.TOWERS_GPKG) == [gpkg]
    assert workdir.zone_files(tmp_path, "other", workdir.PRED) == []


def test_a_block_cache_is_found_from_what_made_it(tmp_path):
    z = tmp_path / "z"
    own = z / workdir.CACHE.format(block="split")  # a block may be named as a batch's folder is
    batch = z / workdir.BATCH_SPLIT.format(batch="b3333_38333")
    assert workdir.block_cache(own, "split") == own
    assert workdir.block_cache(batch, "a") == batch / workdir.CACHE.format(block="a")
    cache = _touch(batch / workdir.CACHE.format(block="a") / "meta.json").parent
    assert workdir.zone_files(tmp_path, "z", workdir.CACHE) == [cache]


def test_a_tiles_conductor_points_are_beside_it(tmp_path):
    for root in (tmp_path / "z", tmp_path / "z" / workdir.BATCH_INFER.format(batch="b3333_38333")):
        tile = root / workdir.TILE.format(block="a", tile="0_1")
        assert workdir.conductors_of(tile) == root / workdir.WIRES.format(block="a", tile="0_1")


def test_a_block_that_left_the_zone_leaves_nothing_behind(tmp_path):
    """A block whose input file is gone: its intermediates (zone layout and batches), logs and
    benchmarks are found and removed; the blocks of the zone, batch records and zone files stay."""
    z = tmp_path / "z"
    batch = z / workdir.BATCH_INFER.format(batch="b3333_38333")
    keep = [
        _touch(z / workdir.TILE.format(block="a.b", tile="0_0")),  # a block id may hold dots
        _touch(z / workdir.TOWERS_GPKG.format(block="a.b")),
        _touch(z / "logs" / "split_block" / "a.b.log"),
        _touch(z / "logs" / "infer_batch" / "b3333_38333.log"),
        _touch(z / "logs" / "plan_zone.log"),
        _touch(z / "registry.gpkg"),
        _touch(batch / workdir.PRED.format(block="c", tile="0_0")),
    ]
    gone = [
        *(
            _touch(z / p.format(block="old", tile="0_1"))
            for p in (workdir.TILE, workdir.PRED, workdir.TOWERS_GPKG, workdir.TOWERS_NEIGHBOURS, workdir.QA_JSON)
        ),
        _touch(z / workdir.CACHE.format(block="old") / "meta.json"),
        _touch(z / "logs" / "split_block" / "old.log"),
        _touch(z / "benchmarks" / "infer_tile" / "old" / "0_1.tsv"),
        _touch(batch / workdir.PRED.format(block="old2", tile="0_0")),
    ]
    found = workdir.gone_blocks(z, ["a.b", "c"])
    assert sorted(found) == ["old", "old2"]
    workdir.remove_gone_blocks(z, ["a.b", "c"])
    assert all(p.exists() for p in keep) and not any(p.exists() for p in gone)
    assert workdir.gone_blocks(z, ["a.b", "c"]) == {}
