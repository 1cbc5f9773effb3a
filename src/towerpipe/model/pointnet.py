"""PointNet_L / PointNet classifier and segmenter (Carós et al. 2022, Fig. 2) and checkpoints.

Architecture (both widths)
--------------------------
``x, y`` (2 columns) -> T-Net (2x2) -> concat ``z`` and the extra features -> shared MLP
to 64 -> feature T-Net (64x64) -> shared MLP to the global width -> max-pool over points.
The classifier head maps the global feature to ``k = 2`` log-probabilities; the segmenter
concatenates each point's 64-d transformed feature with the global feature and maps it to
2 log-probabilities per point. ``z`` is not transformed (towers are not tilted). The full
PointNet (ablation) has the original widths (64-128-1024, FC 512-256); PointNet_L halves
the widths and narrows the T-Net regressors, which takes the parameters from ~3.5 M to
~0.9 M as in the paper. Shared MLPs are ``Linear`` layers on ``(B, N, C)`` tensors (the
same maths as 1x1 convolutions, faster on CPU), batch norm over all points.

A :class:`ModelBundle` is the pair the pipeline ships: a directory with
``classifier.pt``, ``segmenter.pt`` (state dict + hyper-parameters, loaded with
``weights_only=True``), ``model_card.json`` and ``MODEL_CARD.md``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from towerpipe.errors import ModelError
# the shipped-model registry lives in the torch-free modelcard (the Snakefile resolves models
# without importing torch); re-exported here
from towerpipe.model.cards import (BUNDLE_VERSION, MODEL_RELEASES, MODELS_ENV, default_model_path,  # noqa: F401
                                 models_dir, repo_root)

#: Architecture widths. ``conv``: shared MLP after the feature transform; ``tnet_conv`` /
#: ``tnet_fc``: the T-Net point MLP and regressor; ``head``: classifier FC;
#: ``seg_head``: segmentation per-point MLP.
ARCHS: dict[str, dict[str, tuple[int, ...]]] = {
    "light": {"mlp1": (64, 64), "conv": (64, 128, 512), "tnet_conv": (64, 128, 512),
              "tnet_fc": (256, 48), "head": (256, 128), "seg_head": (256, 128, 64)},
    "full": {"mlp1": (64, 64), "conv": (64, 128, 1024), "tnet_conv": (64, 128, 1024),
             "tnet_fc": (512, 256), "head": (512, 256), "seg_head": (512, 256, 128)},
    # half PointNet_L's global width: a third of its cost per window on a CPU
    "compact": {"mlp1": (64, 64), "conv": (64, 128, 256), "tnet_conv": (64, 128, 256),
                "tnet_fc": (128, 48), "head": (128, 64), "seg_head": (128, 64, 32)},
}

#: Points per chunk in :meth:`ModelBundle.segment` / :func:`segment_points`.
DEFAULT_CHUNK = 4096


def _mlp(sizes: tuple[int, ...], in_dim: int) -> nn.ModuleList:
    layers = nn.ModuleList()
    for s in sizes:
        layers.append(nn.ModuleDict({"fc": nn.Linear(in_dim, s), "bn": nn.BatchNorm1d(s)}))
        in_dim = s
    return layers


def _run_mlp(layers: nn.ModuleList, x: torch.Tensor) -> torch.Tensor:
    """Apply Linear+BN+ReLU layers to ``(B, N, C)`` (BN over all B*N points)."""
    b, n, _ = x.shape
    h = x.reshape(b * n, -1)
    for layer in layers:
        h = torch.relu(layer["bn"](layer["fc"](h)))
    return h.reshape(b, n, -1)


class TNet(nn.Module):
    """Regresses a ``k x k`` transform from a point set (initialised at identity)."""

    def __init__(self, k: int, conv: tuple[int, ...], fc: tuple[int, ...]):
        super().__init__()
        self.k = k
        self.conv = _mlp(conv, k)
        self.fc = _mlp(fc, conv[-1])
        self.out = nn.Linear(fc[-1], k * k)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, N, k) -> (B, k, k)
        g = _run_mlp(self.conv, x).amax(dim=1)
        for layer in self.fc:
            g = torch.relu(layer["bn"](layer["fc"](g)))
        eye = torch.eye(self.k, dtype=x.dtype, device=x.device)
        return self.out(g).view(-1, self.k, self.k) + eye


class PointNetBackbone(nn.Module):
    """Shared encoder: per-point 64-d features and the max-pooled global feature.

    Parameters
    ----------
    in_channels
        Input columns; the first two are x, y (transformed by the T-Net).
    arch
        ``"light"`` (PointNet_L) or ``"full"`` (PointNet).
    """

    def __init__(self, in_channels: int, arch: str = "light"):
        super().__init__()
        if arch not in ARCHS:
            raise ModelError(f"unknown architecture {arch!r}; use one of {sorted(ARCHS)}")
        if in_channels < 3:
            raise ModelError(f"need at least x, y, z input columns, got {in_channels}")
        a = ARCHS[arch]
        self.in_channels = in_channels
        self.input_tnet = TNet(2, a["tnet_conv"], a["tnet_fc"])
        self.mlp1 = _mlp(a["mlp1"], in_channels)
        self.feat_dim = a["mlp1"][-1]
        self.feat_tnet = TNet(self.feat_dim, a["tnet_conv"], a["tnet_fc"])
        self.mlp2 = _mlp(a["conv"], self.feat_dim)
        self.global_dim = a["conv"][-1]

    def transforms(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The input (2x2) and feature (64x64) transforms of point sets ``x`` (B, N, C)."""
        t_in = self.input_tnet(x[..., :2])
        h = self._mlp1(x, t_in)
        return t_in, self.feat_tnet(h)

    def _mlp1(self, x: torch.Tensor, t_in: torch.Tensor) -> torch.Tensor:
        xy = torch.bmm(x[..., :2], t_in)
        return _run_mlp(self.mlp1, torch.cat([xy, x[..., 2:]], dim=-1))

    def point_features(self, x: torch.Tensor, t_in: torch.Tensor, t_feat: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-point transformed features (B, N, 64) and pre-pool features (B, N, G)."""
        h = torch.bmm(self._mlp1(x, t_in), t_feat)
        return h, _run_mlp(self.mlp2, h)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``(point_feat (B,N,64), global_feat (B,G), feature_transform (B,64,64))``."""
        t_in, t_feat = self.transforms(x)
        h, g = self.point_features(x, t_in, t_feat)
        return h, g.amax(dim=1), t_feat


def _head(sizes: tuple[int, ...], in_dim: int, n_out: int, dropout: float) -> nn.Sequential:
    mods: list[nn.Module] = []
    for i, s in enumerate(sizes):
        mods += [nn.Linear(in_dim, s), nn.BatchNorm1d(s), nn.ReLU()]
        if dropout > 0 and i == len(sizes) - 1:
            mods.append(nn.Dropout(dropout))
        in_dim = s
    mods.append(nn.Linear(in_dim, n_out))
    return nn.Sequential(*mods)


class PointNetClassifier(nn.Module):
    """Window classifier: ``(B, N, C)`` -> ``(B, k)`` log-probabilities (and the 64x64 transform)."""

    def __init__(self, in_channels: int, arch: str = "light", k: int = 2, dropout: float = 0.3):
        super().__init__()
        self.hparams = {"kind": "classifier", "in_channels": in_channels, "arch": arch, "k": k, "dropout": dropout}
        self.backbone = PointNetBackbone(in_channels, arch)
        self.head = _head(ARCHS[arch]["head"], self.backbone.global_dim, k, dropout)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        _, g, t_feat = self.backbone(x)
        return torch.log_softmax(self.head(g), dim=-1), t_feat


class PointNetSegmenter(nn.Module):
    """Per-point segmenter: ``(B, N, C)`` -> ``(B, N, k)`` log-probabilities (and the transform)."""

    def __init__(self, in_channels: int, arch: str = "light", k: int = 2, dropout: float = 0.0):
        super().__init__()
        self.hparams = {"kind": "segmenter", "in_channels": in_channels, "arch": arch, "k": k, "dropout": dropout}
        self.backbone = PointNetBackbone(in_channels, arch)
        self.head = _head(ARCHS[arch]["seg_head"], self.backbone.feat_dim + self.backbone.global_dim, k, dropout)

    def head_logp(self, h: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """Per-point log-probabilities from point features ``(B,N,64)`` and global ``(B,G)``."""
        b, n, _ = h.shape
        z = torch.cat([h, g[:, None, :].expand(b, n, g.shape[-1])], dim=-1).reshape(b * n, -1)
        return torch.log_softmax(self.head(z), dim=-1).reshape(b, n, -1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h, g, t_feat = self.backbone(x)
        return self.head_logp(h, g), t_feat


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


#: Architectures of :mod:`towerpipe.model.edgeconv` (local geometry), beside the PointNet ones of :data:`ARCHS`.
EDGE_ARCHS = ("edge",)


def build_model(hparams: Mapping[str, Any]) -> nn.Module:
    """Construct a classifier or segmenter from its recorded hyper-parameters (``kind``, ``arch`` ...)."""
    kw = {k: hparams[k] for k in ("in_channels", "arch", "k", "dropout") if k in hparams}
    kind = hparams.get("kind")
    if kind not in ("classifier", "segmenter"):
        raise ModelError(f"unknown model kind {kind!r}")
    if hparams.get("arch") in EDGE_ARCHS:
        from towerpipe.model.edgeconv import EdgeClassifier, EdgeSegmenter

        return (EdgeClassifier if kind == "classifier" else EdgeSegmenter)(**kw)
    return (PointNetClassifier if kind == "classifier" else PointNetSegmenter)(**kw)


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
        return self.folded.classify(torch.from_numpy(np.ascontiguousarray(feats, dtype=np.float32)),
                                    self.chunk).numpy()

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
        out.append(((fc.weight * scale[:, None]).T.contiguous(),
                    ((fc.bias - bn.running_mean) * scale + bn.bias).contiguous()))
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
            self.tin = (_fold(bb.input_tnet.conv), _fold(bb.input_tnet.fc),
                        (bb.input_tnet.out.weight.T.contiguous(), bb.input_tnet.out.bias.clone()))
            self.tfeat = (_fold(bb.feat_tnet.conv), _fold(bb.feat_tnet.fc),
                          (bb.feat_tnet.out.weight.T.contiguous(), bb.feat_tnet.out.bias.clone()))
            self.mlp1, self.mlp2 = _fold(bb.mlp1), _fold(bb.mlp2)
            self.head, self.out = _fold_head(model.head)
        self.kind = model.hparams["kind"]
        self.feat_dim = bb.feat_dim

    @staticmethod
    def _tnet(parts: tuple[Folded, Folded, tuple[torch.Tensor, torch.Tensor]], pooled: torch.Tensor, k: int
              ) -> torch.Tensor:
        w, b = parts[2]
        return (torch.addmm(b, _apply(parts[1], pooled[None]), w).view(k, k) + torch.eye(k, dtype=pooled.dtype))

    def _pool(self, fn, spans) -> torch.Tensor:
        return torch.stack([fn(s, e).amax(dim=0) for s, e in spans]).amax(dim=0)

    def encode(self, x: torch.Tensor, chunk: int
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, list[tuple[int, int]]]:
        """Transforms and global feature of one window ``x`` ``(N, C)``.

        Returns ``(t_in (2,2), t_feat (64,64), global (G,), chunk spans)``; every
        max-pool runs over all ``N`` points, chunk by chunk, so the result does not depend
        on ``chunk``.
        """
        n = x.shape[0]
        spans = [(s, min(s + chunk, n)) for s in range(0, n, chunk)]
        t_in = self._tnet(self.tin, self._pool(lambda s, e: _apply(self.tin[0], x[s:e, :2]), spans), 2)
        t_feat = self._tnet(self.tfeat, self._pool(lambda s, e: _apply(self.tfeat[0], self._mlp1(x[s:e], t_in)),
                                                   spans), self.feat_dim)
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
        w1_point, w1_global = w1[: self.feat_dim], w1[self.feat_dim:]
        b1 = b1 + g @ w1_global
        w, b = self.out
        out = torch.empty(n, dtype=torch.float32)
        for s, e in spans:
            h = torch.addmm(b1, self._mlp1(x[s:e], t_in) @ t_feat, w1_point).relu_()
            out[s:e] = torch.log_softmax(torch.addmm(b, _apply(rest, h), w), dim=-1)[:, 1].exp()
        return out


@torch.inference_mode()
def segment_points(model: PointNetSegmenter | FoldedPointNet, feats: np.ndarray, chunk: int = DEFAULT_CHUNK
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


@dataclass
class ModelBundle:
    """A classifier + segmenter pair with its model card.

    Attributes
    ----------
    name
        Bundle name, e.g. ``"towerpipe-full"``.
    version
        Bundle version string.
    feature_set
        The feature set the models were trained on (``towerpipe.model.features.FEATURE_SETS``).
    card
        The model card (dict, see :mod:`towerpipe.model.cards`).
    n_points
        Points per window the classifier expects (2048).
    classifier, segmenter
        The networks (eval mode). :meth:`classify` and :meth:`segment` run their
        batch-norm-folded copies (:class:`FoldedPointNet`), made when the bundle is built.
    path
        The checkpoint directory it was loaded from (if any).
    """

    name: str
    version: str
    feature_set: str
    card: dict[str, Any]
    n_points: int
    classifier: PointNetClassifier
    segmenter: PointNetSegmenter
    path: Path | None = None
    chunk: int = DEFAULT_CHUNK

    def __post_init__(self) -> None:
        self._runners = (NetRunner(self.classifier, self.n_points, self.chunk),
                         NetRunner(self.segmenter, self.n_points, self.chunk))

    def classify(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability of windows ``feats`` ``(B, n, C)`` float32 -> ``(B,)`` float32."""
        feats = np.asarray(feats, dtype=np.float32)
        if feats.ndim != 3:
            raise ModelError(f"classify expects (B, n, C) features, got shape {feats.shape}")
        if feats.shape[0] == 0:
            return np.zeros(0, dtype=np.float32)
        return self._runners[0].classify(feats)

    def segment(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability of every point of one window ``(N, C)`` -> ``(N,)``."""
        feats = np.asarray(feats, dtype=np.float32)
        if feats.ndim != 2:
            raise ModelError(f"segment expects (N, C) features of one window, got shape {feats.shape}")
        return self._runners[1].segment(feats)


def _state(model: nn.Module) -> dict[str, Any]:
    return {"hparams": dict(model.hparams), "state_dict": model.state_dict(), "bundle_version": BUNDLE_VERSION}


def save_bundle(out_dir: str | os.PathLike[str], classifier: PointNetClassifier, segmenter: PointNetSegmenter,
                card: Mapping[str, Any]) -> Path:
    """Write a checkpoint directory (``classifier.pt``, ``segmenter.pt``, model card json + md).

    Parameters
    ----------
    out_dir
        Target directory (created; files are written to temporary names then renamed).
    classifier, segmenter
        Trained networks.
    card
        Model card (validated with :func:`towerpipe.model.cards.validate_card`).

    Returns
    -------
    pathlib.Path
        ``out_dir``.
    """
    from towerpipe.model import cards as modelcard

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    card = dict(card)
    modelcard.validate_card(card, out / "model_card.json")
    for name, model in (("classifier.pt", classifier), ("segmenter.pt", segmenter)):
        tmp = out / (name + ".part")
        torch.save(_state(model), tmp)
        os.replace(tmp, out / name)
    card["files"] = {n: modelcard.sha256(out / n) for n in ("classifier.pt", "segmenter.pt")}
    modelcard.write_card(out, card)
    return out


def _load_net(path: Path, feature_channels: int, kind: str) -> nn.Module:
    if not path.is_file():
        raise ModelError(f"{path}: missing; the checkpoint directory is incomplete, retrain with `towerpipe train`")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        hp = ckpt["hparams"]
        if hp.get("kind") != kind:
            raise ModelError(f"{path}: holds a {hp.get('kind')!r}, expected a {kind}")
        if int(hp["in_channels"]) != feature_channels:
            raise ModelError(f"{path}: expects {hp['in_channels']} input columns but the model card lists "
                             f"{feature_channels} features; the card and weights do not match, retrain")
        model = build_model(hp)
        model.load_state_dict(ckpt["state_dict"])
    except ModelError:
        raise
    except Exception as exc:  # noqa: BLE001 - any unpickling/shape error is a corrupt checkpoint
        raise ModelError(f"{path}: not a readable towerpipe checkpoint ({exc}); retrain with `towerpipe train`") from exc
    model.eval()
    return model


def load_bundle(path: str | os.PathLike[str]) -> ModelBundle:
    """Load and validate a checkpoint directory written by :func:`save_bundle`.

    Raises
    ------
    ModelError
        Naming the file and the fix when the directory, card or weights are missing,
        corrupt or inconsistent.
    """
    from towerpipe.model import cards as modelcard

    p = Path(path)
    if not p.is_dir():
        raise ModelError(f"{p}: model directory not found; train one with `towerpipe train` or set "
                         f"${MODELS_ENV} to the directory holding towerpipe-<feature_set>-v<release>/")
    card = modelcard.read_card(p)
    n_feat = len(card["features"])
    clf = _load_net(p / "classifier.pt", n_feat, "classifier")
    seg = _load_net(p / "segmenter.pt", n_feat, "segmenter")
    return ModelBundle(name=card["name"], version=str(card["version"]), feature_set=card["feature_set"],
                       card=card, n_points=int(card["sampling"]["n_points"]), classifier=clf, segmenter=seg, path=p)
