"""Disk space: a block refused before its split, and a full disk said in one line wherever it is met."""

from __future__ import annotations

import errno
from collections import namedtuple
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import RGBNIR_SMALL, preprocess_settings
from towerpipe.errors import DiskSpaceError, PdalError
from towerpipe.io import diskspace
from towerpipe.io.diskspace import LOW_SPACE_BYTES, WORK_BYTES_PER_POINT, full_disk_error, require_free
from towerpipe.jobs.smk import run_step
from towerpipe.preprocess.pdal import read_ply_column
from towerpipe.preprocess.split import split_block

_Usage = namedtuple("_Usage", "total used free")


def _disk_with(monkeypatch, free: int) -> None:
    """Every disk seen by towerpipe.io.diskspace has ``free`` bytes free."""
    monkeypatch.setattr(diskspace.shutil, "disk_usage", lambda path: _Usage(10 * 2**30, 10 * 2**30 - free, free))


def test_room_is_asked_for_what_is_written_and_a_margin(tmp_path, monkeypatch):
    _disk_with(monkeypatch, LOW_SPACE_BYTES + 2**30)
    require_free(tmp_path / "not" / "made" / "yet", 2**30, what="block b", fix="do this")  # just enough
    with pytest.raises(DiskSpaceError) as err:
        require_free(tmp_path / "not" / "made" / "yet", 2**30 + 1, what="block b (5 points)", fix="do this")
    msg = str(err.value)
    # the directory that exists (where the files would go), what needs how much, what is free, the fix
    assert msg.startswith(
        f"{tmp_path}: block b (5 points) needs about 1.0 GiB there, 256 MiB more kept free for logs and "
        "temporary files, and 1.2 GiB is free on that disk"
    )
    assert msg.endswith("free space on it or do this")


@pytest.mark.shared
def test_a_block_without_room_for_its_work_files_is_refused_before_its_split(tmp_path, monkeypatch):
    """Refused whatever ``record_errors`` says (a full disk is no fault of the block), nothing written."""
    points = 37_805  # RGBNIR_SMALL
    _disk_with(monkeypatch, LOW_SPACE_BYTES + points * WORK_BYTES_PER_POINT - 1)
    cache = tmp_path / "work" / "z" / "cache" / "b"
    with pytest.raises(DiskSpaceError, match=r"block b \(37,805 points\) needs about 6 MiB .* point `workdir`"):
        split_block(RGBNIR_SMALL, cache, block="b", zone="z", settings=preprocess_settings(), record_errors=True)
    assert not (tmp_path / "work").exists()
    _disk_with(monkeypatch, LOW_SPACE_BYTES + points * WORK_BYTES_PER_POINT)
    assert split_block(RGBNIR_SMALL, cache, block="b", zone="z", settings=preprocess_settings())["points"] == points


def test_a_full_disk_is_found_behind_the_error_a_library_raised(tmp_path):
    full = OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "cache" / "x.npy"))
    try:
        try:
            raise full
        except OSError as exc:
            raise RuntimeError("could not write the cache") from exc
    except RuntimeError as exc:
        err = full_disk_error(exc)
    assert isinstance(err, DiskSpaceError) and err.path == str(tmp_path / "cache" / "x.npy")
    assert "the disk is full (" in str(err) and "`workdir`" in str(err) and "TMPDIR" in str(err)
    # a codec that says it in words (no errno), a quota
    assert full_disk_error(ValueError("IoError: No space left on device (os error 28)")) is not None
    assert full_disk_error(OSError(errno.EDQUOT, "Disk quota exceeded")) is not None
    assert full_disk_error(OSError(errno.EACCES, "Permission denied")) is None
    said = DiskSpaceError(tmp_path, "the disk is full (1 MiB free: [Errno 28] No space left on device)")
    assert full_disk_error(said) is said  # said once, where it was met
    assert full_disk_error(KeyError("x")) is None


def test_a_full_disk_without_a_file_named_is_the_fuller_of_tmpdir_and_the_current_one(tmp_path, monkeypatch):
    tmp, cwd = tmp_path / "tmp", tmp_path / "cwd"
    tmp.mkdir(), cwd.mkdir()
    monkeypatch.setattr(diskspace.tempfile, "gettempdir", lambda: str(tmp))
    monkeypatch.chdir(cwd)
    free = {str(tmp): 2**20, str(cwd): 2**35}
    monkeypatch.setattr(diskspace.shutil, "disk_usage", lambda p: _Usage(2**36, 0, free[str(p)]))
    err = full_disk_error(OSError(errno.ENOSPC, "No space left on device"))
    assert err.path == str(tmp) and "(1 MiB free:" in str(err)
    free[str(tmp)], free[str(cwd)] = 2**35, 2**20
    assert full_disk_error(OSError(errno.ENOSPC, "No space left on device")).path == str(cwd)


def _smk(tmp_path):
    return SimpleNamespace(log=[str(tmp_path / "job.log")], threads=1, rule="split_block", wildcards={"block": "b"})


def test_a_job_that_fills_the_disk_ends_with_one_line_and_status_1(tmp_path, capsys):
    def step():
        np.save(tmp_path / "x.npy", np.zeros(3))  # a write that works, then one that does not
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "y.npy"))

    with pytest.raises(SystemExit) as stop:
        run_step(_smk(tmp_path), step)
    assert stop.value.code == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"towerpipe: DiskSpaceError: {tmp_path / 'y.npy'}: the disk is full (")
    assert "Traceback" not in (tmp_path / "job.log").read_text()

    # a towerpipe error made of a full disk is the disk's
    def pdal_step():
        try:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "z.las"))
        except OSError as exc:
            raise PdalError("pipeline failed") from exc

    with pytest.raises(SystemExit):
        run_step(_smk(tmp_path), pdal_step)
    assert f"towerpipe: DiskSpaceError: {tmp_path / 'z.las'}: the disk is full (" in capsys.readouterr().err
    # any other failure keeps its traceback
    with pytest.raises(ZeroDivisionError):
        run_step(_smk(tmp_path), lambda: 1 / 0)
    assert "Traceback" in (tmp_path / "job.log").read_text()


def test_a_pdal_output_cut_short_on_a_full_disk_says_so(tmp_path, monkeypatch):
    """PDAL 2.2 exits 0 when its writer runs out of room: the PLY it hands back is cut short."""
    short = tmp_path / "hag.ply"
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float32 h\nend_header\n"
    short.write_bytes(head.encode() + np.zeros(3, "<f4").tobytes())
    with pytest.raises(PdalError, match="a truncated file"):
        read_ply_column(short, "h")
    _disk_with(monkeypatch, 2**20)
    with pytest.raises(DiskSpaceError, match=r"hag.ply: 3 points where the header says 4: the disk is full \(1 MiB"):
        read_ply_column(short, "h")


def test_a_disk_that_does_not_say_its_free_space_is_not_refused(tmp_path, monkeypatch):
    def no_answer(path):
        raise OSError(errno.ENOSYS, "not supported")

    monkeypatch.setattr(diskspace.shutil, "disk_usage", no_answer)
    assert diskspace.free_bytes(tmp_path) is None
    require_free(tmp_path, 10**15, what="block b", fix="x")
