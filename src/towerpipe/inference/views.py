"""Test-time views of a window: the segmenter on the window turned and mirrored about its centre.

With ``inference.tta`` > 1 each segmented window also goes through the segmenter turned
(and mirrored) about its centre; :func:`segment_views` gives the window as it is and the
mean over the views (:mod:`towerpipe.inference.infer` writes both).
"""

from __future__ import annotations

import numpy as np

from towerpipe.errors import ConfigError
from towerpipe.inference.compat import BundleLike

__all__ = ["TTA_CHOICES", "check_views", "segment_views"]

#: test-time views of a window's plan, in the order they are added: the window as it is,
#: the half turn, the quarter turns, then the mirror images (x -> -x etc.). Each is the
#: matrix (a, b, c, d): x' = a x + b y, y' = c x + d y, on the first two feature columns.
_TTA_VIEWS = (
    (1, 0, 0, 1),
    (-1, 0, 0, -1),
    (0, -1, 1, 0),
    (0, 1, -1, 0),
    (-1, 0, 0, 1),
    (0, 1, 1, 0),
    (1, 0, 0, -1),
    (0, -1, -1, 0),
)
TTA_CHOICES = (1, 2, 4, 8)


def check_views(views: int) -> None:
    """Raise :class:`ConfigError` unless ``views`` is one of :data:`TTA_CHOICES`."""
    if views not in TTA_CHOICES:
        raise ConfigError(f"inference.tta must be one of {TTA_CHOICES}, got {views!r}")


def segment_views(bundle: BundleLike, feats: np.ndarray, views: int) -> tuple[np.ndarray, np.ndarray]:
    """Segmenter probability of each point: the window as it is, and the mean over ``views`` views.

    2 and 4 views add the window turned by 180 and by 90 / 270 degrees about its centre,
    8 adds their mirror images. The views are exact (the plan coordinates are permuted
    and negated, no resampling). A tower looks like a tower from every side; a crown
    that the segmenter paints in one view seldom scores as high in all of them, so the
    mean trims the uncertain edge of a tower. It also lowers the whole of a tower the
    segmenter is unsure of, which is why towers are found on the single view
    (:mod:`towerpipe.towers.extract`) and only their points are chosen on the mean.

    Parameters
    ----------
    bundle
        The model (its ``segment``).
    feats
        ``(N, C)`` float32 features of one window; columns 0 and 1 are the plan
        coordinates relative to the window centre.
    views
        One of :data:`TTA_CHOICES`; 1 is the plain segmenter.

    Returns
    -------
    single, mean
        ``(N,)`` float32 probabilities (the same array when ``views`` is 1).
    """
    check_views(views)
    single = np.asarray(bundle.segment(feats), dtype=np.float32).reshape(-1)
    if views == 1:
        return single, single
    acc = single.copy()
    xy = np.array(feats[:, :2], dtype=np.float32)
    f = np.array(feats, dtype=np.float32)
    for a, b, c, d in _TTA_VIEWS[1:views]:
        f[:, 0] = a * xy[:, 0] + b * xy[:, 1]
        f[:, 1] = c * xy[:, 0] + d * xy[:, 1]
        acc += np.asarray(bundle.segment(f), dtype=np.float32).reshape(-1)
    return single, acc / np.float32(views)
