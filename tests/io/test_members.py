"""Tower-points files: the tower id of each point of a block, and the points of each tower in it."""

from __future__ import annotations

import numpy as np

from towerpipe.io.members import member_counts, member_ids, save_members


def test_member_counts_are_the_ids_member_ids_gives(tmp_path):
    # tower 1 of block a; tower 2 across the seam of a and b; file two gives point 7 of a to tower 3
    one = tmp_path / "one.npz"
    save_members(
        one,
        {
            1: (np.array(["a"] * 4, dtype=object), np.array([0, 1, 2, 7])),
            2: (np.array(["a", "a", "b", "b", "b"], dtype=object), np.array([10, 11, 0, 1, 2])),
        },
    )
    two = tmp_path / "two.npz"
    save_members(two, {3: (np.array(["a", "a"], dtype=object), np.array([7, 12]))})
    ids = member_ids([one, two], "a", 20)
    expected = {int(t): int((ids == t).sum()) for t in np.unique(ids[ids > 0])}
    assert member_counts([one, two], "a", 20) == expected == {1: 3, 2: 2, 3: 2}
    assert member_counts([one], "b", 3) == {2: 3}
    assert member_counts([two], "b", 3) == {}
