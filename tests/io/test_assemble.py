"""Publishing a directory atomically (towerpipe.io.atomic): never deleted first, no leftovers."""

from __future__ import annotations

import errno
import os
import threading
from pathlib import Path

import pytest

from towerpipe.io.atomic import assemble_directory, publish_copy, staging_path, swap_in, write_text_atomic


def _leftovers(root: Path) -> list[str]:
    return sorted(p.name for p in root.rglob("*") if p.name.endswith((".part", ".staging", ".old")))


def test_directory_exists_at_every_moment_of_repeated_swaps(tmp_path):
    src = tmp_path / "src.txt"
    src.write_text("x")
    out = tmp_path / "zone"
    assemble_directory(out, {"a.txt": src})
    missing, stop = [], threading.Event()

    def poll():
        while not stop.is_set():
            if not (out / "a.txt").is_file():
                missing.append(1)

    t = threading.Thread(target=poll)
    t.start()
    try:
        for i in range(200):
            assemble_directory(out, {"a.txt": src, f"b{i}.txt": src})
    finally:
        stop.set()
        t.join()
    assert missing == []
    assert sorted(p.name for p in out.iterdir()) == ["a.txt", "b199.txt"]
    assert _leftovers(tmp_path) == []


def test_failure_while_building_keeps_the_published_directory(tmp_path):
    src = tmp_path / "src.txt"
    src.write_text("old")
    out = tmp_path / "zone"
    assemble_directory(out, {"a.txt": src})

    def full_disk(tmp):
        (tmp / "INCOMPLETE.txt").write_text("half")
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        assemble_directory(out, {"a.txt": src, "b.txt": src}, full_disk)
    assert sorted(p.name for p in out.iterdir()) == ["a.txt"]
    assert not staging_path(out).exists() and _leftovers(tmp_path) == []
    with pytest.raises(FileNotFoundError):
        assemble_directory(out, {"c.txt": tmp_path / "missing"})
    assert sorted(p.name for p in out.iterdir()) == ["a.txt"] and _leftovers(tmp_path) == []


def test_text_written_on_a_full_disk_leaves_no_part_file(tmp_path, monkeypatch):
    import builtins

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def write(self, text):
            self.fh.write(text[:10])  # a few bytes land, then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("towerpipe.io.atomic.open", lambda *a, **k: Full(builtins.open(*a, **k)), raising=False)
    path = tmp_path / "INCOMPLETE.txt"
    path.write_text("previous")
    with pytest.raises(OSError) as exc:
        write_text_atomic(path, "x" * 100_000)
    assert exc.value.errno == errno.ENOSPC
    assert path.read_text() == "previous" and sorted(p.name for p in tmp_path.iterdir()) == ["INCOMPLETE.txt"]


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full to fill a write")
def test_columns_written_on_a_full_disk_leave_no_part_file(tmp_path):
    import numpy as np

    from towerpipe.io.columns import save_columns

    os.symlink("/dev/full", tmp_path / "t.npz.part")
    with pytest.raises(OSError):
        save_columns(tmp_path / "t.npz", {"x": np.zeros(100_000)}, {})
    assert list(tmp_path.iterdir()) == []


def test_swap_in_and_copy(tmp_path):
    a = tmp_path / "a"
    a.mkdir()
    (a / "f").write_text("1")
    out = tmp_path / "out"
    publish_copy(a, out)
    assert (out / "f").read_text() == "1" and os.stat(out / "f").st_ino == os.stat(a / "f").st_ino
    b = tmp_path / "b"
    b.mkdir()
    (b / "g").write_text("2")
    swap_in(b, out)
    assert [p.name for p in out.iterdir()] == ["g"] and not b.exists()
