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
