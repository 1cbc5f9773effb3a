"""Scores of trained networks on training windows: window F1 and point IoU.

:func:`classification_metrics` and :func:`segmentation_metrics` score predictions against
labels; :func:`predict_windows` and :func:`segment_windows_metrics` run a trained network
on windows of a :class:`~towerpipe.training.windowset.WindowSet` as at inference
(:class:`towerpipe.model.folded.NetRunner`), for the training loop and the evaluation.
"""

from __future__ import annotations

import numpy as np
import torch

from towerpipe.model.folded import NetRunner
from towerpipe.model.folded_numpy import DEFAULT_CHUNK
from towerpipe.model.pointnet import PointNetClassifier, PointNetSegmenter
from towerpipe.training.windowset import WindowSet


def _f1(tp: int, fp: int, fn: int) -> dict[str, float]:
    p = tp / (tp + fp) if tp + fp else 0.0
    r = tp / (tp + fn) if tp + fn else 0.0
    return {"precision": p, "recall": r, "f1": 2 * p * r / (p + r) if p + r else 0.0}


def classification_metrics(prob: np.ndarray, label: np.ndarray, threshold: float = 0.5) -> dict[str, float]:
    """F1, precision, recall and accuracy of window probabilities against labels."""
    pred = np.asarray(prob) >= threshold
    lab = np.asarray(label).astype(bool)
    tp, fp, fn = int((pred & lab).sum()), int((pred & ~lab).sum()), int((~pred & lab).sum())
    out = _f1(tp, fp, fn)
    out.update(accuracy=float((pred == lab).mean()) if lab.size else 0.0, n=int(lab.size), positives=int(lab.sum()))
    return out


def segmentation_metrics(pred: np.ndarray, label: np.ndarray) -> dict[str, float]:
    """IoU of the tower class, of the background and their mean (points pooled over windows)."""
    p = np.asarray(pred).astype(bool)
    t = np.asarray(label).astype(bool)
    inter_t, union_t = int((p & t).sum()), int((p | t).sum())
    inter_b, union_b = int((~p & ~t).sum()), int((~p | ~t).sum())
    iou_t = inter_t / union_t if union_t else 1.0
    iou_b = inter_b / union_b if union_b else 1.0
    return {
        "iou_tower": iou_t,
        "iou_background": iou_b,
        "miou": (iou_t + iou_b) / 2,
        "points": int(t.size),
        "tower_points": int(t.sum()),
    }


@torch.inference_mode()
def predict_windows(
    model: PointNetClassifier, ws: WindowSet, idx: np.ndarray, feature_set: str, sampling: str = "constrained"
) -> np.ndarray:
    """Tower probability of the sampled windows ``idx`` (eval-mode statistics, as at inference)."""
    runner = NetRunner(model, ws.n_points)
    out = [runner.classify(ws.sampled(idx[s : s + 64], feature_set, sampling)[0]) for s in range(0, len(idx), 64)]
    return np.concatenate(out) if out else np.zeros(0, np.float32)


def segment_windows_metrics(
    model: PointNetSegmenter,
    ws: WindowSet,
    idx: np.ndarray,
    feature_set: str,
    threshold: float = 0.5,
    chunk: int = DEFAULT_CHUNK,
) -> dict[str, float]:
    """IoU tower / background / mIoU on *all* points of the positive windows among ``idx``.

    Each window goes through :func:`towerpipe.model.folded.segment_points`, as at inference.
    """
    runner = NetRunner(model, ws.n_points, chunk)
    pos = idx[ws.label[idx] == 1]
    preds, labs = [], []
    for i in pos:
        f, lab = ws.window_points(int(i), feature_set)
        preds.append(runner.segment(f) >= threshold)
        labs.append(lab)
    out = segmentation_metrics(
        np.concatenate(preds) if preds else np.zeros(0, bool), np.concatenate(labs) if labs else np.zeros(0, bool)
    )
    out["windows"] = int(len(pos))
    return out
