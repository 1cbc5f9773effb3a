"""Fixed-size point sampling for PointNet windows (Carós et al. 2022, sec. 3.2).

Constrained sampling removes clutter before the model sees it: a window with more
than ``n`` points first loses points below 3 m HAG (low vegetation), then, if still
too many, points below 8 m (medium vegetation), and only then is the rest sampled at
random. Points are removed *only as many as needed*: if dropping some of the points
below 3 m is enough, the others are kept, chosen uniformly at random.

Windows with fewer than ``n`` points are padded: every point is kept once and
``n - m`` extra indices are drawn uniformly *with replacement*. Duplicates do not change
a max-pooled PointNet feature, so the padded window is seen as the original one.
"""

from __future__ import annotations

import numpy as np

#: Height bands (m HAG) of constrained sampling, thinned in this order.
DEFAULT_BANDS: tuple[float, ...] = (3.0, 8.0)


def _pad(m: int, n: int, rng: np.random.Generator) -> np.ndarray:
    if m <= 0:
        raise ValueError("cannot sample from an empty window")
    if m >= n:
        return np.arange(n, dtype=np.int64) if m == n else np.sort(rng.choice(m, n, replace=False)).astype(np.int64)
    extra = rng.integers(0, m, size=n - m)
    return np.concatenate([np.arange(m, dtype=np.int64), np.sort(extra).astype(np.int64)])


def random_sample(m: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform random sampling of ``n`` of ``m`` points (the ablation's baseline).

    Parameters
    ----------
    m
        Number of points in the window (> 0).
    n
        Number of points wanted.
    rng
        Random generator (results are deterministic given its state).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` int64 indices in ``[0, m)``; without replacement when ``m >= n``,
        otherwise all points once plus ``n - m`` drawn with replacement.
    """
    return _pad(int(m), int(n), rng)


def constrained_sample(
    hag: np.ndarray, n: int = 2048, rng: np.random.Generator | None = None, bands: tuple[float, ...] = DEFAULT_BANDS
) -> np.ndarray:
    """Constrained sampling to exactly ``n`` points.

    Parameters
    ----------
    hag
        Height above ground of the window's points, shape ``(m,)``.
    n
        Number of points wanted.
    rng
        Random generator (default: ``numpy.random.default_rng(0)``).
    bands
        Increasing HAG thresholds: points with ``hag < bands[0]`` are removed first,
        then those with ``hag < bands[1]``, ... (only as many as needed).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` int64 indices into ``hag``, sorted (padding indices follow the
        originals when ``m < n``).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    hag = np.asarray(hag)
    m = hag.size
    if m <= n:
        return _pad(m, n, rng)
    keep = np.ones(m, dtype=bool)
    excess = m - n
    for threshold in bands:
        cand = np.flatnonzero(keep & (hag < threshold))
        if cand.size == 0:
            continue
        if cand.size >= excess:
            keep[rng.choice(cand, excess, replace=False)] = False
            return np.flatnonzero(keep).astype(np.int64)
        keep[cand] = False
        excess -= cand.size
    rest = np.flatnonzero(keep)
    return np.sort(rng.choice(rest, n, replace=False)).astype(np.int64)
