"""Class-balanced negative log-likelihood (Cui et al. 2019, as used by Carós et al. 2022)."""

from __future__ import annotations

import numpy as np
import torch


def effective_number(counts: np.ndarray, beta: float) -> np.ndarray:
    """Effective number of samples ``(1 - beta**n) / (1 - beta)`` per class.

    Parameters
    ----------
    counts
        Samples per class.
    beta
        Hyper-parameter in ``[0, 1)``.
    """
    if not 0.0 <= beta < 1.0:
        raise ValueError(f"beta must be in [0, 1), got {beta}")
    n = np.asarray(counts, dtype=np.float64)
    return (1.0 - np.power(beta, n)) / (1.0 - beta)


def class_balanced_weights(counts: np.ndarray, beta: float) -> np.ndarray:
    """Class weights proportional to ``1 / E_n`` and normalised to sum to the number of classes.

    Classes with no samples get weight 0 before normalisation (they never occur).

    Parameters
    ----------
    counts
        Samples per class (e.g. ``[negatives, positives]``).
    beta
        0.9, 0.999 or 0.9999 in the paper.

    Returns
    -------
    numpy.ndarray
        float64 weights, ``weights.sum() == len(counts)``.
    """
    counts = np.asarray(counts, dtype=np.float64)
    en = effective_number(counts, beta)
    inv = np.divide(1.0, en, out=np.zeros_like(en), where=en > 0)
    if inv.sum() == 0:
        return np.ones_like(counts)
    return inv / inv.sum() * len(counts)


def weighted_nll(logp: torch.Tensor, target: torch.Tensor, weights: torch.Tensor | None) -> torch.Tensor:
    """Weighted NLL of log-probabilities ``(M, k)`` (or ``(B, N, k)``) and integer targets.

    The mean is normalised by the summed weights of the targets (PyTorch's convention).
    """
    k = logp.shape[-1]
    return torch.nn.functional.nll_loss(logp.reshape(-1, k), target.reshape(-1), weight=weights)


def feature_transform_regulariser(t: torch.Tensor) -> torch.Tensor:
    """PointNet's orthogonality penalty ``mean ||I - T T^T||_F`` on ``(B, k, k)`` transforms."""
    eye = torch.eye(t.shape[-1], dtype=t.dtype, device=t.device)
    return torch.linalg.matrix_norm(eye - torch.bmm(t, t.transpose(1, 2))).mean()
