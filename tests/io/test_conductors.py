"""Conductor-points files (towerpipe.io.conductors)."""

import numpy as np
import pytest

from towerpipe.errors import InputError
from towerpipe.io.conductors import CONDUCTOR_ARRAYS, load_conductors, save_conductors


def test_conductor_files_round_trip_and_concatenate(tmp_path):
    rng = np.random.default_rng(0)
    parts = [{k: rng.normal(size=n) for k in CONDUCTOR_ARRAYS} for n in (5, 0, 3)]
    paths = [tmp_path / f"{i}.npz" for i in range(len(parts))]
    for p, part in zip(paths, parts):
        save_conductors(p, part, {"block": "b"})
    out = load_conductors(paths)
    for k in CONDUCTOR_ARRAYS:
        np.testing.assert_array_equal(out[k], np.concatenate([q[k] for q in parts]))
    assert all(len(v) == 0 for v in load_conductors([]).values())


def test_a_conductor_file_that_is_not_one_names_itself_and_the_job_to_rerun(tmp_path):
    bad = tmp_path / "0_0.npz"
    bad.write_bytes(b"not a npz")
    with pytest.raises(InputError, match=r"0_0\.npz.*infer_tile"):
        load_conductors([bad])
