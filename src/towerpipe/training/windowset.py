"""The training window container: :class:`WindowSet`, its file and its summary.

The windows themselves are built by :mod:`towerpipe.training.dataset` (see its module
docstring); this module holds what a built set is: the pooled float16 point features and
labels, the constrained and random sample indices, the window labels, kinds
(:data:`KINDS`), splits (:data:`SPLITS`), blocks, centres and tower families
(:data:`FAMILY_BITS`), and how it is written to and read from an ``.npz`` and summarised
for the model card.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.errors import InputError
from towerpipe.model.features import ALL_FEATURES, FEATURE_SETS

#: Bit of each tower family in a window's ``family`` mask (real families: :data:`towerpipe.synth.real.FAMILIES`).
FAMILY_BITS: dict[str, int] = {"synthetic": 1, "ts40k": 2, "uav": 4, "utility": 8}

#: Window kinds (``kind`` array).
KINDS = {"random_negative": 0, "tall_negative": 1, "positive": 2, "positive_shifted": 3, "hard_negative": 4}
SPLITS = {"train": 0, "val": 1, "test": 2}


@dataclass
class WindowSet:
    """Built training windows (see the module docstring of :mod:`towerpipe.training.dataset`).

    Attributes
    ----------
    feat
        ``(P, len(ALL_FEATURES))`` float16 pooled point features of all windows.
    point_label
        ``(P,)`` uint8, 1 = tower point.
    offsets
        ``(W + 1,)`` int64: window ``i`` owns pool rows ``offsets[i]:offsets[i+1]``.
    cs_idx, rs_idx
        ``(W, n_points)`` int32 constrained / random sample indices into the window's rows.
    label, kind, split, block_id
        ``(W,)`` window label (1 = tower), kind (:data:`KINDS`), split (:data:`SPLITS`),
        index into ``meta["blocks"]``.
    family
        ``(W,)`` uint8 mask of the tower families (:data:`FAMILY_BITS`) in the window (0:
        no tower, or no truth known).
    center
        ``(W, 2)`` float64 window centres.
    meta
        Build configuration, blocks, split assignment, per-tile counts, colour availability.
    """

    feat: np.ndarray
    point_label: np.ndarray
    offsets: np.ndarray
    cs_idx: np.ndarray
    rs_idx: np.ndarray
    label: np.ndarray
    kind: np.ndarray
    split: np.ndarray
    block_id: np.ndarray
    center: np.ndarray
    family: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.label)

    @property
    def n_points(self) -> int:
        """Points per sampled window."""
        return int(self.cs_idx.shape[1])

    def indices(self, split: str) -> np.ndarray:
        """Window indices of a split (``train``, ``val`` or ``test``)."""
        return np.flatnonzero(self.split == SPLITS[split])

    def columns(self, feature_set: str) -> list[int]:
        """Column indices of ``feature_set`` in :attr:`feat`."""
        return [ALL_FEATURES.index(c) for c in FEATURE_SETS[feature_set]]

    def window_points(self, i: int, feature_set: str) -> tuple[np.ndarray, np.ndarray]:
        """All stored points of window ``i``: ``(features (m, C) float32, labels (m,) int64)``."""
        s, e = self.offsets[i], self.offsets[i + 1]
        return (self.feat[s:e][:, self.columns(feature_set)].astype(np.float32), self.point_label[s:e].astype(np.int64))

    def sampled(
        self, idx: np.ndarray, feature_set: str, sampling: str = "constrained"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sampled windows ``idx``: ``(B, n, C)`` float32 features and ``(B, n)`` int64 labels."""
        samp = {"constrained": self.cs_idx, "random": self.rs_idx}[sampling]
        rows = self.offsets[np.asarray(idx)][:, None] + samp[np.asarray(idx)]
        cols = self.columns(feature_set)
        return self.feat[rows][..., cols].astype(np.float32), self.point_label[rows].astype(np.int64)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write an uncompressed ``.npz`` atomically."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".part")
        arrays = {
            k: getattr(self, k)
            for k in (
                "feat",
                "point_label",
                "offsets",
                "cs_idx",
                "rs_idx",
                "label",
                "kind",
                "split",
                "block_id",
                "center",
                "family",
            )
        }
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.frombuffer(json.dumps(self.meta).encode(), dtype=np.uint8), **arrays)
        os.replace(tmp, path)
        return path


def load_windows(path: str | os.PathLike[str]) -> WindowSet:
    """Read a :class:`WindowSet` written by :meth:`WindowSet.save`."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            arrays = {k: z[k] for k in z.files if k != "meta"}
        arrays.setdefault("family", np.zeros(len(arrays["label"]), np.uint8))
        return WindowSet(meta=meta, **arrays)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(
            path, f"not a towerpipe windows file ({exc}); rebuild it with towerpipe.training.dataset"
        ) from exc


def is_windows_file(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is a windows ``.npz`` (rather than a tile file)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return "offsets" in z.files and "cs_idx" in z.files
    except (OSError, ValueError):
        return False


def summarise(ws: WindowSet) -> dict[str, Any]:
    """Window and point counts per split (for the model card)."""
    out: dict[str, Any] = {}
    for name, code in SPLITS.items():
        sel = ws.split == code
        pos = np.flatnonzero(sel & (ws.label == 1))
        tower_pts = int(sum(int(ws.point_label[ws.offsets[i] : ws.offsets[i + 1]].sum()) for i in pos))
        out[name] = {
            "windows": int(sel.sum()),
            "positive": int((ws.label[sel] == 1).sum()),
            "negative": int((ws.label[sel] == 0).sum()),
            "positive_by_family": {f: int(((ws.family[pos] & bit) > 0).sum()) for f, bit in FAMILY_BITS.items()},
            "blocks": sorted({ws.meta["blocks"][b] for b in np.unique(ws.block_id[sel])})
            if "blocks" in ws.meta
            else [],
            "tower_points_in_positives": tower_pts,
        }
    return out
