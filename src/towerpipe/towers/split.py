"""Rule 9, the split: the parts of a cluster the shape check drops, judged instead of it.

A tower standing among crowns the segmenter paints with it makes one cluster with them, and the
object under that cluster is shaped like a tree. Its more confident parts (its points at or above
each of ``towers.split_thresholds`` in turn), and once none parts it, its own points linked again
at ``towers.split_linkage`` (:data:`RELINK`), are judged by the tower rules instead
(:func:`towerpipe.towers.extract.extract_towers`; docs/model.md, the split and "A dropped cluster
linked again").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["RELINK", "split_parts"]

#: The last step of a split (rule 9), after its probability thresholds: the cluster's own points
#: linked again at ``towers.split_linkage``.
RELINK = "relink"


def split_parts(
    g: np.ndarray,
    prob: np.ndarray,
    cluster: Callable[[np.ndarray], np.ndarray],
    steps: Sequence[float | str],
    relink: Callable[[np.ndarray], np.ndarray] | None = None,
) -> list[tuple[np.ndarray, tuple[float | str, ...]]]:
    """The parts of a cluster ``g`` the shape check dropped (rule 9), each with the steps left after it.

    Each of ``steps`` in turn until one gives a part: a probability clusters ``g``'s points at or above
    it (``cluster(idx)`` labels the points ``idx``); :data:`RELINK` labels all of ``g``'s points
    with ``relink`` (a tighter linkage), and counts only when it parts them.
    """
    for i, step in enumerate(steps):
        if step == RELINK:
            if relink is None:
                continue
            sub, lab = g, relink(g)
            if (lab >= 0).all() and not lab.any():
                continue  # one part, the cluster itself
        else:
            sub = g[prob[g] >= step]
            lab = cluster(sub)
        if (lab >= 0).any():
            return [(sub[lab == k], tuple(steps[i + 1 :])) for k in range(int(lab.max()) + 1)]
    return []
