"""A model bundle whose networks load on the first window that needs them.

A tile with nothing tall enough for a window (open land, a small block of low vegetation)
needs neither network, so :class:`LazyBundle` reads the model card at once (name, version,
feature set, points per window: what the compatibility check and the prediction file's
metadata need) and loads the networks only on the first :meth:`~LazyBundle.classify`:
their folded copies (:class:`towerpipe.model.folded_numpy.FoldedPair`, NumPy, a few
milliseconds) when the bundle has them, else the checkpoints through PyTorch
(:func:`towerpipe.model.bundle.load_bundle`: about 1.5 s, most of it ``import torch``).
Both give the same probabilities.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.model.cards import bundle_identity, read_card
from towerpipe.model.folded_numpy import FoldedPair, has_folded


class LazyBundle:
    """The model bundle in ``path``: its card now, its networks when a window needs them.

    Attributes
    ----------
    name, version, feature_set, card, n_points, path
        As :class:`towerpipe.model.bundle.ModelBundle`, from the model card.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_dir():  # load_bundle names the directory and the fix
            from towerpipe.model.bundle import load_bundle

            load_bundle(self.path)
        self.card: dict[str, Any] = read_card(self.path)
        identity = bundle_identity(self.card)
        self.name: str = identity["name"]
        self.version: str = identity["version"]
        self.feature_set: str = identity["feature_set"]
        self.n_points: int = identity["n_points"]
        self._bundle = None
        #: Seconds spent loading the networks (0 until they are loaded).
        self.load_s = 0.0

    @property
    def loaded(self) -> bool:
        """Whether the networks have been loaded."""
        return self._bundle is not None

    def _networks(self):
        if self._bundle is None:
            t0 = time.perf_counter()
            if has_folded(self.card):
                self._bundle = FoldedPair(self.path)
            else:
                from towerpipe.model.bundle import load_bundle

                self._bundle = load_bundle(self.path, self.card)  # the card and checksums are read once
            self.load_s = time.perf_counter() - t0
        return self._bundle

    def classify(self, feats: np.ndarray) -> np.ndarray:
        """:meth:`towerpipe.model.bundle.ModelBundle.classify` (loads the networks)."""
        return self._networks().classify(feats)

    def segment(self, feats: np.ndarray) -> np.ndarray:
        """:meth:`towerpipe.model.bundle.ModelBundle.segment` (loads the networks)."""
        return self._networks().segment(feats)
