"""PointNet inference in NumPy from batch-norm-folded weights: no PyTorch at inference.

A trained PointNet classifier or segmenter (:mod:`towerpipe.model.pointnet`) is, in eval
mode, a chain of ``relu(h @ W + b)`` layers, two small transforms and max-pools once each
batch norm is folded into its ``Linear`` (:func:`towerpipe.model.folded.fold_pointnet`).
:class:`FoldedNet` runs that chain on float32 NumPy arrays, so an inference job needs
neither ``import torch`` (about 1.5 s a job) nor the checkpoint's unpickling: the model
bundle stores the folded arrays beside each checkpoint (:data:`FOLDED_FILES`, written by
:func:`towerpipe.model.bundle.save_bundle`, checksummed in the model card).

Every inference path (the pipeline's jobs, the calibration, the training's validation
and the evaluation) runs this class, so a window gets the same probabilities wherever it
is scored.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from towerpipe.errors import ModelError

#: Points per chunk of :meth:`FoldedNet.segment` (the max-pools span all chunks: any value gives the same result).
DEFAULT_CHUNK = 4096

#: The folded inference arrays of each network of a bundle, beside ``<kind>.pt``.
FOLDED_FILES: dict[str, str] = {"classifier": "classifier.folded.npz", "segmenter": "segmenter.folded.npz"}

#: The layer groups of a folded PointNet, each a list of ``(W (in, out), b (out,))``;
#: ``*.out`` and ``out`` are the single output layers (no ReLU).
GROUPS = ("tin.conv", "tin.fc", "tin.out", "tfeat.conv", "tfeat.fc", "tfeat.out", "mlp1", "mlp2", "head", "out")

Layers = list[tuple[np.ndarray, np.ndarray]]


def _relu_layers(layers: Layers, h: np.ndarray) -> np.ndarray:
    """``relu(h @ W + b)`` for each layer; ``h`` is ``(M, C)``."""
    for w, b in layers:
        h = h @ w
        h += b
        np.maximum(h, 0.0, out=h)
    return h


def _tower_prob(logits: np.ndarray) -> np.ndarray:
    """Probability of class 1 from ``(M, 2)`` logits (``exp`` of the log-softmax)."""
    return np.exp(logits[:, 1] - np.logaddexp(logits[:, 0], logits[:, 1])).astype(np.float32)


class FoldedNet:
    """A batch-norm-folded PointNet classifier or segmenter on NumPy arrays.

    Parameters
    ----------
    arrays
        ``kind`` (``"classifier"`` or ``"segmenter"``) and, for each group of
        :data:`GROUPS`, ``<group>.<i>.w`` ``(in, out)`` and ``<group>.<i>.b`` ``(out,)``
        float32 arrays (:func:`towerpipe.model.folded.fold_pointnet`).
    """

    def __init__(self, arrays: Mapping[str, np.ndarray]):
        self.kind = str(np.asarray(arrays["kind"]))
        if self.kind not in FOLDED_FILES:
            raise ModelError(f"folded network of unknown kind {self.kind!r}")
        self.layers: dict[str, Layers] = {}
        for g in GROUPS:
            layers, i = [], 0
            while f"{g}.{i}.w" in arrays:
                w = np.ascontiguousarray(arrays[f"{g}.{i}.w"], dtype=np.float32)
                b = np.ascontiguousarray(arrays[f"{g}.{i}.b"], dtype=np.float32)
                layers.append((w, b))
                i += 1
            self.layers[g] = layers
        missing = [g for g in GROUPS if g not in ("tin.fc", "tfeat.fc", "head") and not self.layers[g]]
        if missing:
            raise ModelError(f"folded {self.kind} lacks the layer group(s) {', '.join(missing)}")
        self.feat_dim = int(self.layers["mlp1"][-1][0].shape[1])

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays it was built from (what :func:`save_folded` writes)."""
        out: dict[str, np.ndarray] = {"kind": np.asarray(self.kind)}
        for g, layers in self.layers.items():
            for i, (w, b) in enumerate(layers):
                out[f"{g}.{i}.w"], out[f"{g}.{i}.b"] = w, b
        return out

    # ---- the encoder ------------------------------------------------------------------
    def _tnet(self, which: str, pooled: np.ndarray) -> np.ndarray:
        ((w, b),) = self.layers[f"{which}.out"]
        k = int(round(np.sqrt(w.shape[1])))
        t = _relu_layers(self.layers[f"{which}.fc"], pooled[None]) @ w + b
        return t.reshape(k, k) + np.eye(k, dtype=np.float32)

    def _mlp1(self, x: np.ndarray, t_in: np.ndarray) -> np.ndarray:
        return _relu_layers(self.layers["mlp1"], np.concatenate([x[:, :2] @ t_in, x[:, 2:]], axis=1))

    @staticmethod
    def _pool(fn, spans: list[tuple[int, int]]) -> np.ndarray:
        return np.max([fn(s, e).max(axis=0) for s, e in spans], axis=0)

    def encode(self, x: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]]:
        """Transforms and global feature of one window ``x`` ``(N, C)``.

        Returns ``(t_in (2,2), t_feat (64,64), global (G,), chunk spans)``; every
        max-pool runs over all ``N`` points, chunk by chunk, so the result does not depend
        on ``chunk``.
        """
        n = x.shape[0]
        spans = [(s, min(s + chunk, n)) for s in range(0, n, chunk)]
        t_in = self._tnet("tin", self._pool(lambda s, e: _relu_layers(self.layers["tin.conv"], x[s:e, :2]), spans))
        t_feat = self._tnet(
            "tfeat",
            self._pool(lambda s, e: _relu_layers(self.layers["tfeat.conv"], self._mlp1(x[s:e], t_in)), spans),
        )
        g = self._pool(lambda s, e: _relu_layers(self.layers["mlp2"], self._mlp1(x[s:e], t_in) @ t_feat), spans)
        return t_in, t_feat, g, spans

    # ---- the heads --------------------------------------------------------------------
    def classify(self, x: np.ndarray, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
        """Tower probability of each window of ``x`` ``(B, N, C)`` -> ``(B,)``, one window at a time."""
        if self.kind != "classifier":
            raise ModelError("classify needs a classifier")
        x = np.asarray(x, dtype=np.float32)
        if not len(x):
            return np.zeros(0, dtype=np.float32)
        ((w, b),) = self.layers["out"]
        g = np.stack([self.encode(x[i], chunk)[2] for i in range(x.shape[0])])
        return _tower_prob(_relu_layers(self.layers["head"], g) @ w + b)

    def segment(self, x: np.ndarray, chunk: int = DEFAULT_CHUNK) -> np.ndarray:
        """Tower probability of every point of one window ``x`` ``(N, C)`` -> ``(N,)``.

        The first head layer acts on ``[point feature, global feature]``; its global part
        is the same for every point and is computed once per window.
        """
        if self.kind != "segmenter":
            raise ModelError("segment needs a segmenter")
        x = np.asarray(x, dtype=np.float32)
        n = x.shape[0]
        if n == 0:
            return np.zeros(0, dtype=np.float32)
        t_in, t_feat, g, spans = self.encode(x, chunk)
        (w1, b1), rest = self.layers["head"][0], self.layers["head"][1:]
        w1_point, b1 = w1[: self.feat_dim], b1 + g @ w1[self.feat_dim :]
        ((w, b),) = self.layers["out"]
        out = np.empty(n, dtype=np.float32)
        for s, e in spans:
            h = _relu_layers([(w1_point, b1), *rest], self._mlp1(x[s:e], t_in) @ t_feat)
            out[s:e] = _tower_prob(h @ w + b)
        return out


def window_batch(feats: np.ndarray) -> np.ndarray:
    """``feats`` as float32 ``(B, n, C)`` windows (what a classifier takes), or a ModelError."""
    feats = np.asarray(feats, dtype=np.float32)
    if feats.ndim != 3:
        raise ModelError(f"classify expects (B, n, C) features, got shape {feats.shape}")
    return feats


def one_window(feats: np.ndarray) -> np.ndarray:
    """``feats`` as float32 ``(N, C)`` points of one window (what a segmenter takes), or a ModelError."""
    feats = np.asarray(feats, dtype=np.float32)
    if feats.ndim != 2:
        raise ModelError(f"segment expects (N, C) features of one window, got shape {feats.shape}")
    return feats


class FoldedPair:
    """A bundle's classifier and segmenter as :class:`FoldedNet`, read from its folded files.

    What :class:`towerpipe.model.lazy.LazyBundle` runs when the bundle has them: the same
    :meth:`classify` and :meth:`segment` as :class:`towerpipe.model.bundle.ModelBundle`,
    with the same probabilities, without importing PyTorch.
    """

    def __init__(self, path: str | os.PathLike[str], chunk: int = DEFAULT_CHUNK):
        self.path, self.chunk = Path(path), int(chunk)
        self.classifier = load_folded(self.path / FOLDED_FILES["classifier"], "classifier")
        self.segmenter = load_folded(self.path / FOLDED_FILES["segmenter"], "segmenter")

    def classify(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability of windows ``feats`` ``(B, n, C)`` -> ``(B,)`` float32."""
        return self.classifier.classify(window_batch(feats), self.chunk)

    def segment(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability of every point of one window ``(N, C)`` -> ``(N,)``."""
        return self.segmenter.segment(one_window(feats), self.chunk)


def has_folded(card: Mapping[str, object]) -> bool:
    """Whether the bundle of ``card`` lists (and so checksums) both folded files."""
    files = card.get("files")
    return isinstance(files, Mapping) and all(f in files for f in FOLDED_FILES.values())


def save_folded(net: FoldedNet, path: str | os.PathLike[str]) -> Path:
    """Write ``net``'s arrays to ``path`` (``.npz``, uncompressed: it loads in milliseconds).

    Byte for byte the same for the same network (the archive's time stamps are fixed), so
    its checksum in the model card names the weights, not the moment they were written.
    """
    p = Path(path)
    tmp = p.with_name(p.name + ".part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zf:
        for key, value in net.arrays().items():
            with zf.open(zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0)), "w") as f:
                np.lib.format.write_array(f, np.asarray(value), allow_pickle=False)
    os.replace(tmp, p)
    return p


def load_folded(path: str | os.PathLike[str], kind: str) -> FoldedNet:
    """Read a network written by :func:`save_folded`, checking that it is a ``kind``."""
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            net = FoldedNet({k: z[k] for k in z.files})
    except ModelError as exc:
        raise ModelError(f"{p}: {exc}; write the bundle again with `towerpipe fold-model`") from exc
    except (OSError, ValueError, KeyError) as exc:
        raise ModelError(
            f"{p}: not a readable folded network ({exc}); write it again with `towerpipe fold-model`"
        ) from exc
    if net.kind != kind:
        raise ModelError(f"{p}: holds a {net.kind!r}, expected a {kind}")
    return net
