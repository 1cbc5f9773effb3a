"""Tests of towerpipe.io.lasformat: the writer of points whose header statistics are known."""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from towerpipe.io.lasformat import KnownStatsWriter


def _points(n: int, point_format: int = 3) -> laspy.PackedPointRecord:
    rng = np.random.default_rng(0)
    header = laspy.LasHeader(point_format=point_format, version="1.2")
    records = laspy.ScaleAwarePointRecord.zeros(n, header=header).array
    records["X"] = rng.integers(0, 10_000, n)
    records["Y"] = rng.integers(0, 10_000, n)
    records["Z"] = rng.integers(0, 3_000, n)
    records["bit_fields"] = 1 | (1 << 3)  # return 1 of 1
    return laspy.PackedPointRecord(records, laspy.PointFormat(point_format))


@pytest.mark.parametrize("compress", [False, True])
def test_the_writer_counts_the_points_and_keeps_the_statistics_it_is_given(tmp_path, compress):
    """Chunks written one by one come back whole, and the header says what was set on it, not what
    laspy would measure (the merge sets the input's bounds and counts by return)."""
    points = _points(25_000)
    header = laspy.LasHeader(point_format=3, version="1.2")
    path = tmp_path / ("out.laz" if compress else "out.las")
    with KnownStatsWriter(open(path, "wb+"), header, do_compress=compress) as writer:
        for start in range(0, len(points), 10_000):
            writer.write_points(points[start : start + 10_000])
        writer.header.mins = np.array([-1.0, -2.0, -3.0])
        writer.header.maxs = np.array([100.0, 200.0, 300.0])
        writer.header.number_of_points_by_return = np.array([25_000, 0, 0, 0, 0])
    back = laspy.read(path)
    assert back.header.point_count == len(points)
    assert np.array_equal(back.points.array, points.array)
    assert back.header.mins.tolist() == [-1.0, -2.0, -3.0] and back.header.maxs.tolist() == [100.0, 200.0, 300.0]
    assert back.header.number_of_points_by_return.tolist()[:1] == [25_000]


def test_the_writer_refuses_another_point_format_and_points_after_closing(tmp_path):
    header = laspy.LasHeader(point_format=3, version="1.2")
    writer = KnownStatsWriter(open(tmp_path / "out.las", "wb+"), header)
    with pytest.raises(laspy.errors.LaspyException, match="Incompatible"):
        writer.write_points(_points(10, point_format=1))
    writer.close()
    with pytest.raises(laspy.errors.LaspyException, match="anymore"):
        writer.write_points(_points(10))
