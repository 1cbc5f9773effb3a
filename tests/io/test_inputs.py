"""Block ids and fingerprints (towerpipe.io.inputs)."""

from __future__ import annotations

import os
import re
import shutil

from towerpipe.io.inputs import block_ids, find_blocks, fingerprint, scan_zone


def test_plain_names_are_kept_and_odd_ones_made_safe_and_unique():
    ids = block_ids(
        [
            "a.laz",
            "f2/upper_case.LAZ",
            "b c.laz",
            "blk{1}.laz",
            "é.laz",
            "flight1/a.laz",
            "flight1__a.laz",
            "x.las",
            "x.laz",
            ".hidden.laz",
        ]
    )
    rel = {r: b for b, r in ids.items()}
    assert rel["a.laz"] == "a" and rel["f2/upper_case.LAZ"] == "f2__upper_case"
    for r in ("b c.laz", "blk{1}.laz", "é.laz", "flight1/a.laz", "flight1__a.laz", "x.las", "x.laz", ".hidden.laz"):
        assert re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*-[0-9a-f]{8}", rel[r]), rel[r]
    assert len(set(ids)) == len(ids) == 10
    assert rel["é.laz"].startswith("e-") and rel["blk{1}.laz"].startswith("blk_1_-")


def test_ids_do_not_depend_on_the_other_files():
    assert block_ids(["b c.laz"]) == {k: v for k, v in block_ids(["b c.laz", "z.laz"]).items() if v == "b c.laz"}


def test_fingerprint_sees_content_not_time(tmp_path):
    a = tmp_path / "a.laz"
    data = bytearray(os.urandom(5 << 20))
    a.write_bytes(data)
    fp = fingerprint(a)
    st = a.stat()
    data[-10] ^= 0xFF  # one byte in the last MiB (the LAZ chunk table, EVLRs)
    a.write_bytes(data)
    os.utime(a, ns=(st.st_atime_ns - 10**16, st.st_mtime_ns - 10**16))  # an older mtime
    assert fingerprint(a) != fp
    fp = fingerprint(a)
    # one point's class byte edited in place in an uncompressed file, between any samples
    # a partial hash would read (its size, header and ends unchanged): still another file
    data[(5 << 20) // 2 + 12_345] ^= 0x07
    a.write_bytes(data)
    assert fingerprint(a) != fp
    b = tmp_path / "b.laz"
    shutil.copy2(a, b)  # cp -p: same content, same mtime
    assert fingerprint(b) == fingerprint(a)


def test_scan_zone_caches_by_stat_and_flags_two_files_of_one_block(tmp_path):
    d = tmp_path / "in"
    (d / "sub").mkdir(parents=True)
    (d / "x.las").write_bytes(b"1" * 100)
    (d / "x.laz").write_bytes(b"2" * 100)
    (d / "sub" / "y.laz").write_bytes(b"3" * 100)
    cache = tmp_path / "inputs.json"
    found = scan_zone(d, cache)
    assert sorted(i.relpath for i in found.values()) == ["sub/y.laz", "x.las", "x.laz"]
    clash = {i.relpath: i.clash for i in found.values()}
    assert clash == {"sub/y.laz": None, "x.las": "x.laz", "x.laz": "x.las"}
    assert all(i.header is None for i in found.values())  # not LAS: the split says why
    # content replaced, mtime set back: a new fingerprint (the stat cache sees the ctime)
    y = d / "sub" / "y.laz"
    st = y.stat()
    y.write_bytes(b"4" * 100)
    os.utime(y, ns=(st.st_atime_ns, st.st_mtime_ns))
    again = scan_zone(d, cache)
    assert again["sub__y"].fingerprint != found["sub__y"].fingerprint
    assert find_blocks(d) == {b: i.path for b, i in again.items()}


def test_a_record_of_the_sampled_recipe_stands_while_its_file_is_unchanged(tmp_path):
    """An upgrade reruns no block: the cache's version-1 fingerprint is kept while the file's
    stat holds; once the file changes, it is read whole."""
    import json

    d = tmp_path / "in"
    d.mkdir()
    x = d / "x.laz"
    x.write_bytes(b"1" * 100)
    cache = tmp_path / "inputs.json"
    scan_zone(d, cache)
    rec = json.loads(cache.read_text())
    rec["x.laz"].update(version=1, fingerprint="0123456789abcdef01234567")
    cache.write_text(json.dumps(rec))
    assert scan_zone(d, cache)["x"].fingerprint == "0123456789abcdef01234567"
    x.write_bytes(b"2" * 100)
    assert scan_zone(d, cache)["x"].fingerprint == fingerprint(x) != "0123456789abcdef01234567"


def test_hidden_files_and_folders_are_not_blocks(tmp_path):
    """macOS's ``._x.laz`` beside ``x.laz`` on a share, a ``.snapshot`` folder: not blocks."""
    d = tmp_path / "in"
    (d / ".snapshot").mkdir(parents=True)
    (d / "x.laz").write_bytes(b"1")
    (d / "._x.laz").write_bytes(b"2")
    (d / ".snapshot" / "x.laz").write_bytes(b"1")
    assert list(find_blocks(d)) == ["x"]


def test_a_readable_file_of_zero_points_is_empty_an_unreadable_one_is_not(tmp_path):
    import laspy

    from towerpipe.io.inputs import is_empty

    d = tmp_path / "in"
    d.mkdir()
    laspy.LasData(laspy.LasHeader(point_format=6, version="1.4")).write(d / "sea.laz")
    (d / "broken.laz").write_bytes(b"not a las file")
    found = scan_zone(d)
    assert is_empty(found["sea"]) and not is_empty(found["broken"])  # the split says what is wrong with it
