"""Inference with one trained network: batch norm folded into the PointNet layers.

:class:`FoldedPointNet` is the inference-only copy of a trained PointNet classifier or
segmenter (:mod:`towerpipe.model.pointnet`), :func:`segment_points` segments one window of any
size with it chunk by chunk, and :class:`NetRunner` runs a network of either family
(PointNet folded, EdgeConv through :mod:`towerpipe.model.edgeconv`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from towerpipe.errors import ModelError
from towerpipe.model.pointnet import EDGE_ARCHS, PointNetClassifier, PointNetSegmenter

#: Points per chunk in :meth:`towerpipe.model.bundle.ModelBundle.segment` / :func:`segment_points`.
DEFAULT_CHUNK = 4096


class NetRunner:
    """Inference with one trained network: PointNet batch-norm folded (:class:`FoldedPointNet`),
    EdgeConv through :mod:`towerpipe.model.edgeconv` (sampled segmentation)."""

    def __init__(self, model: nn.Module, n_points: int, chunk: int = DEFAULT_CHUNK):
        model.eval()
        self.model, self.n_points, self.chunk = model, int(n_points), int(chunk)
        self.edge = model.hparams.get("arch") in EDGE_ARCHS
        self.folded = None if self.edge else FoldedPointNet(model)

    @torch.inference_mode()
    def classify(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability ``(B,)`` of windows ``(B, n, C)``."""
        if self.edge:
            from towerpipe.model import edgeconv

            return edgeconv.classify(self.model, feats)
        return self.folded.classify(torch.from_numpy(np.ascontiguousarray(feats, dtype=np.float32)), self.chunk).numpy()

    def segment(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability ``(N,)`` of every point of one window ``(N, C)``."""
        if self.edge:
            from towerpipe.model import edgeconv

            return edgeconv.segment(self.model, feats, self.n_points)
        return segment_points(self.folded, feats, self.chunk)


Folded = list[tuple[torch.Tensor, torch.Tensor]]


def _fold(layers: nn.ModuleList) -> Folded:
    """Fold each eval-mode ``Linear + BatchNorm`` of a shared MLP into one ``(W^T, b)`` pair."""
    out = []
    for layer in layers:
        fc, bn = layer["fc"], layer["bn"]
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        out.append(
            ((fc.weight * scale[:, None]).T.contiguous(), ((fc.bias - bn.running_mean) * scale + bn.bias).contiguous())
        )
    return out


def _fold_head(head: nn.Sequential) -> tuple[Folded, tuple[torch.Tensor, torch.Tensor]]:
    """Fold a :func:`_head` (``[Linear, BN, ReLU, (Dropout)]* Linear``) into MLP layers + output."""
    mods = [m for m in head if not isinstance(m, (nn.ReLU, nn.Dropout))]
    hidden = nn.ModuleList(nn.ModuleDict({"fc": fc, "bn": bn}) for fc, bn in zip(mods[:-1:2], mods[1:-1:2]))
    return _fold(hidden), (mods[-1].weight.T.contiguous(), mods[-1].bias.contiguous())


def _apply(folded: Folded, h: torch.Tensor) -> torch.Tensor:
    """``relu(h @ W + b)`` for each folded layer; ``h`` is ``(M, C)``."""
    for w, b in folded:
        h = torch.addmm(b, h, w).relu_()
    return h


class FoldedPointNet:
    """Inference-only view of a trained classifier or segmenter with batch norm folded away.

    In eval mode batch norm is an affine map per channel, so each ``Linear + BN`` pair is
    one ``Linear``; with ReLU applied in place and one window at a time (point chunks for
    large windows), the intermediate arrays stay small. The result equals the module's
    eval-mode output to float32 rounding (about 1e-5) and is ~3.5x faster on CPU than the
    module, whose time goes mostly into memory-bound batch-norm, ReLU and bias copies on
    ``(B * N, 512)`` arrays. The module's weights are copied at construction time.

    Parameters
    ----------
    model
        A :class:`PointNetClassifier` or :class:`PointNetSegmenter` (its eval-mode statistics are used).
    """

    def __init__(self, model: PointNetClassifier | PointNetSegmenter):
        bb = model.backbone
        with torch.no_grad():
            self.tin = (
                _fold(bb.input_tnet.conv),
                _fold(bb.input_tnet.fc),
                (bb.input_tnet.out.weight.T.contiguous(), bb.input_tnet.out.bias.clone()),
            )
            self.tfeat = (
                _fold(bb.feat_tnet.conv),
                _fold(bb.feat_tnet.fc),
                (bb.feat_tnet.out.weight.T.contiguous(), bb.feat_tnet.out.bias.clone()),
            )
            self.mlp1, self.mlp2 = _fold(bb.mlp1), _fold(bb.mlp2)
            self.head, self.out = _fold_head(model.head)
        self.kind = model.hparams["kind"]
        self.feat_dim = bb.feat_dim

    @staticmethod
    def _tnet(
        parts: tuple[Folded, Folded, tuple[torch.Tensor, torch.Tensor]], pooled: torch.Tensor, k: int
    ) -> torch.Tensor:
        w, b = parts[2]
        return torch.addmm(b, _apply(parts[1], pooled[None]), w).view(k, k) + torch.eye(k, dtype=pooled.dtype)

    def _pool(self, fn, spans) -> torch.Tensor:
        return torch.stack([fn(s, e).amax(dim=0) for s, e in spans]).amax(dim=0)

    def encode(
        self, x: torch.Tensor, chunk: int
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, list[tuple[int, int]]]:
        """Transforms and global feature of one window ``x`` ``(N, C)``.

        Returns ``(t_in (2,2), t_feat (64,64), global (G,), chunk spans)``; every
        max-pool runs over all ``N`` points, chunk by chunk, so the result does not depend
        on ``chunk``.
        """
        n = x.shape[0]
        spans = [(s, min(s + chunk, n)) for s in range(0, n, chunk)]
        t_in = self._tnet(self.tin, self._pool(lambda s, e: _apply(self.tin[0], x[s:e, :2]), spans), 2)
        t_feat = self._tnet(
            self.tfeat, self._pool(lambda s, e: _apply(self.tfeat[0], self._mlp1(x[s:e], t_in)), spans), self.feat_dim
        )
        g = self._pool(lambda s, e: _apply(self.mlp2, self._mlp1(x[s:e], t_in) @ t_feat), spans)
        return t_in, t_feat, g, spans

    def _mlp1(self, x: torch.Tensor, t_in: torch.Tensor) -> torch.Tensor:
        return _apply(self.mlp1, torch.cat([x[:, :2] @ t_in, x[:, 2:]], dim=1))

    def classify(self, x: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
        """Tower probability of each window of ``x`` ``(B, N, C)`` -> ``(B,)``, one window at a time."""
        if self.kind != "classifier":
            raise ModelError("classify needs a classifier")
        out = torch.empty(x.shape[0], dtype=torch.float32)
        w, b = self.out
        for i in range(x.shape[0]):
            g = self.encode(x[i], chunk)[2]
            out[i] = torch.log_softmax(torch.addmm(b, _apply(self.head, g[None]), w), dim=-1)[0, 1].exp()
        return out

    def segment(self, x: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
        """Tower probability of every point of one window ``x`` ``(N, C)`` -> ``(N,)``.

        The first head layer acts on ``[point feature, global feature]``; its global part
        is the same for every point and is computed once per window.
        """
        if self.kind != "segmenter":
            raise ModelError("segment needs a segmenter")
        n = x.shape[0]
        if n == 0:
            return torch.zeros(0, dtype=torch.float32)
        t_in, t_feat, g, spans = self.encode(x, chunk)
        (w1, b1), rest = self.head[0], self.head[1:]
        w1_point, w1_global = w1[: self.feat_dim], w1[self.feat_dim :]
        b1 = b1 + g @ w1_global
        w, b = self.out
        out = torch.empty(n, dtype=torch.float32)
        for s, e in spans:
            h = torch.addmm(b1, self._mlp1(x[s:e], t_in) @ t_feat, w1_point).relu_()
            out[s:e] = torch.log_softmax(torch.addmm(b, _apply(rest, h), w), dim=-1)[:, 1].exp()
        return out


@torch.inference_mode()
def segment_points(
    model: PointNetSegmenter | FoldedPointNet, feats: np.ndarray, chunk: int = DEFAULT_CHUNK
) -> np.ndarray:
    """Tower probability of every point of one window, exact for any number of points.

    The transforms are estimated on the whole window (the T-Nets max-pool, so they are
    computed chunk by chunk and combined by max), then the per-point features are
    computed in chunks, max-pooled over *all* points, and the per-point head is applied
    in chunks (see :class:`FoldedPointNet`). The module's eval-mode statistics are used.

    Parameters
    ----------
    model
        A :class:`PointNetSegmenter` (folded on each call) or its :class:`FoldedPointNet`.
    feats
        ``(N, C)`` float32 features of one window.
    chunk
        Points per chunk.

    Returns
    -------
    numpy.ndarray
        ``(N,)`` float32 probability of class 1 (tower).
    """
    folded = model if isinstance(model, FoldedPointNet) else FoldedPointNet(model)
    x = torch.from_numpy(np.ascontiguousarray(feats, dtype=np.float32))
    return folded.segment(x, int(chunk)).numpy()
