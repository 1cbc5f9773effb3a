"""The linkage graph of a cluster's points: its connected components (:func:`components`) and,
from seed points, the seed each point is nearest to along it (:func:`nearest_seed`).

:mod:`towerpipe.towers.cluster` links towers and splits wide components with it,
:mod:`towerpipe.towers.masts` and :mod:`towerpipe.towers.peaks` give each point of a cluster to one of
its masts or peaks.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree


def components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component labels (int64) of ``n`` nodes joined by ``pairs`` (k, 2)."""
    if n == 0:
        return np.empty(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def nearest_seed(
    xyz: np.ndarray,
    seeds: np.ndarray,
    seed_labels: np.ndarray,
    linkage: float,
    limit: float = np.inf,
    *,
    everywhere: bool = False,
) -> np.ndarray:
    """The label of the seed each point is nearest to along the graph of points closer than
    ``linkage`` (3-D, edges weighted by length).

    Parameters
    ----------
    xyz
        (n, 3) coordinates.
    seeds
        Indices of the seed points.
    seed_labels
        The label of each seed.
    linkage
        Points closer than this (m) are joined.
    limit
        Points further than this (m, along the graph) from every seed are not reached.
    everywhere
        The points no seed reaches take the label of the seed nearest in 3-D.

    Returns
    -------
    numpy.ndarray
        (n,) int64 labels, -1 for the points no seed reaches (never with ``everywhere``).
    """
    n = len(xyz)
    pairs = cKDTree(xyz).query_pairs(linkage, output_type="ndarray")
    w = np.linalg.norm(xyz[pairs[:, 0]] - xyz[pairs[:, 1]], axis=1) + 1e-9
    graph = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    dist, _, source = dijkstra(
        graph, directed=False, indices=seeds, min_only=True, limit=limit, return_predecessors=True
    )
    reached = np.isfinite(dist) & (source >= 0)
    of_seed = np.full(n, -1, np.int64)
    of_seed[seeds] = seed_labels
    labels = np.full(n, -1, np.int64)
    labels[reached] = of_seed[source[reached]]
    if everywhere and not reached.all():
        lost = ~reached
        labels[lost] = of_seed[seeds][cKDTree(xyz[seeds]).query(xyz[lost])[1]]
    return labels
