"""Model bundles: the classifier + segmenter pair the pipeline ships, saved and loaded.

A :class:`ModelBundle` is the pair the pipeline ships: a directory with
``classifier.pt``, ``segmenter.pt`` (state dict + hyper-parameters, loaded with
``weights_only=True``), their batch-norm-folded copies for inference without PyTorch
(``classifier.folded.npz``, ``segmenter.folded.npz``: :mod:`towerpipe.model.folded_numpy`;
PointNet architectures only), ``model_card.json`` (with the checksum of every file) and
``MODEL_CARD.md``.
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
from towerpipe.model.cards import BUNDLE_VERSION, MODELS_ENV
from towerpipe.model.folded import NetRunner, fold_pointnet
from towerpipe.model.folded_numpy import DEFAULT_CHUNK, FOLDED_FILES, one_window, save_folded, window_batch
from towerpipe.model.pointnet import EDGE_ARCHS, PointNetClassifier, PointNetSegmenter, build_model


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
        batch-norm-folded copies (:func:`~towerpipe.model.folded.fold_pointnet`), made when the bundle is built.
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
        self._runners = (
            NetRunner(self.classifier, self.n_points, self.chunk),
            NetRunner(self.segmenter, self.n_points, self.chunk),
        )

    def classify(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability of windows ``feats`` ``(B, n, C)`` float32 -> ``(B,)`` float32."""
        feats = window_batch(feats)
        if feats.shape[0] == 0:
            return np.zeros(0, dtype=np.float32)
        return self._runners[0].classify(feats)

    def segment(self, feats: np.ndarray) -> np.ndarray:
        """Tower probability of every point of one window ``(N, C)`` -> ``(N,)``."""
        return self._runners[1].segment(one_window(feats))


def _state(model: nn.Module) -> dict[str, Any]:
    return {"hparams": dict(model.hparams), "state_dict": model.state_dict(), "bundle_version": BUNDLE_VERSION}


def save_bundle(
    out_dir: str | os.PathLike[str],
    classifier: PointNetClassifier,
    segmenter: PointNetSegmenter,
    card: Mapping[str, Any],
) -> Path:
    """Write a checkpoint directory (``classifier.pt``, ``segmenter.pt``, their folded copies, model card json + md).

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
    modelcard.validate_card(card, out / modelcard.CARD_FILE)
    for name, model in zip(modelcard.WEIGHT_FILES, (classifier, segmenter), strict=True):
        tmp = out / (name + ".part")
        torch.save(_state(model), tmp)
        os.replace(tmp, out / name)
    card["files"] = {n: modelcard.sha256(out / n) for n in modelcard.WEIGHT_FILES}
    card["files"].update(_save_folded(out, classifier, segmenter))
    modelcard.write_card(out, card)
    return out


def _save_folded(out: Path, classifier: nn.Module, segmenter: nn.Module) -> dict[str, str]:
    """Write the folded copies of a PointNet pair into ``out``: ``{file name: sha256}`` ({} for EdgeConv)."""
    from towerpipe.model import cards as modelcard

    if any(m.hparams.get("arch") in EDGE_ARCHS for m in (classifier, segmenter)):
        return {}
    files = {}
    for kind, model in (("classifier", classifier), ("segmenter", segmenter)):
        name = FOLDED_FILES[kind]
        save_folded(fold_pointnet(model.eval()), out / name)
        files[name] = modelcard.sha256(out / name)
    return files


def fold_bundle(path: str | os.PathLike[str]) -> dict[str, str]:
    """Add the folded copies to a bundle saved without them (a bundle of towerpipe < 0.7).

    Loads the checkpoints (checksums checked), writes ``classifier.folded.npz`` and
    ``segmenter.folded.npz`` and lists them in ``model_card.json``; the weights and
    ``MODEL_CARD.md`` are left as they are. Returns the files written with their checksums.
    """
    from towerpipe.model import cards as modelcard

    bundle = load_bundle(path)
    files = _save_folded(Path(path), bundle.classifier, bundle.segmenter)
    if not files:
        raise ModelError(f"{path}: an EdgeConv bundle has no folded copy; it runs through PyTorch")
    card = dict(bundle.card)
    card["files"] = {**card["files"], **files}
    modelcard.write_card_json(path, card)
    return files


def _load_net(path: Path, feature_channels: int, kind: str) -> nn.Module:
    if not path.is_file():
        raise ModelError(f"{path}: missing; the checkpoint directory is incomplete, retrain with `towerpipe train`")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        hp = ckpt["hparams"]
        if hp.get("kind") != kind:
            raise ModelError(f"{path}: holds a {hp.get('kind')!r}, expected a {kind}")
        if int(hp["in_channels"]) != feature_channels:
            raise ModelError(
                f"{path}: expects {hp['in_channels']} input columns but the model card lists "
                f"{feature_channels} features; the card and weights do not match, retrain"
            )
        model = build_model(hp)
        model.load_state_dict(ckpt["state_dict"])
    except ModelError:
        raise
    except Exception as exc:  # noqa: BLE001 - any unpickling/shape error is a corrupt checkpoint
        raise ModelError(
            f"{path}: not a readable towerpipe checkpoint ({exc}); retrain with `towerpipe train`"
        ) from exc
    model.eval()
    return model


def load_bundle(path: str | os.PathLike[str], card: Mapping[str, Any] | None = None) -> ModelBundle:
    """Load and validate a checkpoint directory written by :func:`save_bundle`.

    ``card``: its model card, already read (:func:`towerpipe.model.cards.read_card`, which
    validates it and checks the weights' checksums); ``None``: read here.

    Raises
    ------
    ModelError
        Naming the file and the fix when the directory, card or weights are missing,
        corrupt or inconsistent.
    """
    from towerpipe.model import cards as modelcard

    p = Path(path)
    if not p.is_dir():
        raise ModelError(
            f"{p}: model directory not found; train one with `towerpipe train` or set "
            f"${MODELS_ENV} to the directory holding towerpipe-<feature_set>-v<release>/"
        )
    card = dict(card) if card is not None else modelcard.read_card(p)
    n_feat = len(card["features"])
    clf, seg = (_load_net(p / f, n_feat, kind) for f, kind in zip(modelcard.WEIGHT_FILES, ("classifier", "segmenter")))
    return ModelBundle(**modelcard.bundle_identity(card), card=card, classifier=clf, segmenter=seg, path=p)
