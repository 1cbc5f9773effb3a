"""Timing one training step, to size epochs to a CPU budget."""

from __future__ import annotations

import time

import numpy as np
import torch

from towerpipe.model.features import FEATURE_SETS
from towerpipe.model.pointnet import PointNetClassifier, PointNetSegmenter
from towerpipe.training.losses import feature_transform_regulariser, weighted_nll


def time_batch(
    kind: str = "classifier",
    arch: str = "light",
    feature_set: str = "full",
    n_points: int = 2048,
    batch_size: int = 32,
    repeats: int = 3,
    threads: int = 2,
) -> float:
    """Median seconds of one training step (forward + backward + Adam) on random data, on CPU.

    Use it to size epochs to a time budget: ``epochs * ceil(windows / batch_size) * time_batch()``.
    """
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    c = len(FEATURE_SETS[feature_set])
    model = (PointNetClassifier if kind == "classifier" else PointNetSegmenter)(c, arch)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    x = torch.rand(batch_size, n_points, c) - 0.5
    y = torch.randint(0, 2, (batch_size,) if kind == "classifier" else (batch_size, n_points))
    times = []
    for _ in range(repeats + 1):
        t = time.perf_counter()
        logp, t_feat = model(x)
        loss = weighted_nll(logp, y, None) + 0.001 * feature_transform_regulariser(t_feat)
        opt.zero_grad()
        loss.backward()
        opt.step()
        times.append(time.perf_counter() - t)
    return float(np.median(times[1:]))
