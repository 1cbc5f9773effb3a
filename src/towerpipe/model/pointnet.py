"""PointNet_L / PointNet classifier and segmenter (Carós et al. 2022, Fig. 2).

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

The batch-norm-folded inference copy of a trained network is in :mod:`towerpipe.model.folded`,
the checkpoint bundle (classifier + segmenter + model card) in :mod:`towerpipe.model.bundle`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import nn

from towerpipe.errors import ModelError

#: Architecture widths. ``conv``: shared MLP after the feature transform; ``tnet_conv`` /
#: ``tnet_fc``: the T-Net point MLP and regressor; ``head``: classifier FC;
#: ``seg_head``: segmentation per-point MLP.
ARCHS: dict[str, dict[str, tuple[int, ...]]] = {
    "light": {
        "mlp1": (64, 64),
        "conv": (64, 128, 512),
        "tnet_conv": (64, 128, 512),
        "tnet_fc": (256, 48),
        "head": (256, 128),
        "seg_head": (256, 128, 64),
    },
    "full": {
        "mlp1": (64, 64),
        "conv": (64, 128, 1024),
        "tnet_conv": (64, 128, 1024),
        "tnet_fc": (512, 256),
        "head": (512, 256),
        "seg_head": (512, 256, 128),
    },
    # half PointNet_L's global width: a third of its cost per window on a CPU
    "compact": {
        "mlp1": (64, 64),
        "conv": (64, 128, 256),
        "tnet_conv": (64, 128, 256),
        "tnet_fc": (128, 48),
        "head": (128, 64),
        "seg_head": (128, 64, 32),
    },
}


def _mlp(sizes: tuple[int, ...], in_dim: int) -> nn.ModuleList:
    layers = nn.ModuleList()
    for s in sizes:
        layers.append(nn.ModuleDict({"fc": nn.Linear(in_dim, s), "bn": nn.BatchNorm1d(s)}))
        in_dim = s
    return layers


def max_pool(h: torch.Tensor) -> torch.Tensor:
    """Max over the points of ``(B, N, C)`` features: ``(B, C)``.

    ``max(dim).values`` rather than ``amax``: the forward values are the same, and so is the
    gradient except where several points tie for the maximum (duplicated sample points),
    where ``amax`` spreads it evenly over them and ``max`` gives it to one, the same sum.
    ``amax``'s backward builds three ``(B, N, C)`` temporaries (equality mask, count,
    product), ``max``'s scatters ``B x C`` values: training a shipped model takes about 7 %
    less CPU time (CHANGELOG 0.8.2).
    """
    return h.max(dim=1).values


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
        g = max_pool(_run_mlp(self.conv, x))
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

    def point_features(
        self, x: torch.Tensor, t_in: torch.Tensor, t_feat: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-point transformed features (B, N, 64) and pre-pool features (B, N, G)."""
        h = torch.bmm(self._mlp1(x, t_in), t_feat)
        return h, _run_mlp(self.mlp2, h)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return ``(point_feat (B,N,64), global_feat (B,G), feature_transform (B,64,64))``."""
        t_in, t_feat = self.transforms(x)
        h, g = self.point_features(x, t_in, t_feat)
        return h, max_pool(g), t_feat


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
