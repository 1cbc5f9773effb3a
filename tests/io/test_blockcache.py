"""The block cache's column reader: a column read a piece at a time, through mappings released with each read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from towerpipe.io.blockcache import BlockCache, ColumnReader


def mapped(path: Path) -> bool:
    """Whether this process maps ``path`` (Linux: /proc/self/maps; elsewhere: unknown, False)."""
    maps = Path("/proc/self/maps")
    return maps.exists() and str(path) in maps.read_text()


def test_a_reader_gives_copies_and_keeps_no_mapping(tmp_path):
    values = np.arange(10_000, dtype="f8") * 0.25
    with BlockCache.create(tmp_path / "c") as w:
        s = w.column_writer("x", len(values))
        s.write(values[:6000])
        s.write(values[6000:])
        s.close()
        w.write_meta({"points": len(values)})
    cache = BlockCache.open(tmp_path / "c")
    reader = cache.reader("x")
    assert isinstance(reader, ColumnReader)
    assert len(reader) == len(values) and reader.dtype == values.dtype and reader.shape == values.shape
    part = reader[1000:3000]
    assert type(part) is np.ndarray and np.array_equal(part, values[1000:3000])
    mask = values % 7 == 0
    assert np.array_equal(reader[mask], values[mask])
    assert np.array_equal(reader[[5, 3, 9999]], values[[5, 3, 9999]])
    assert not mapped(cache.column_path("x")), "a read must release its mapping"
    assert np.array_equal(np.asarray(reader), values)
    assert np.asarray(reader, dtype="f4").dtype == np.float32
