"""Effective-number class weights (Cui et al. 2019) and the weighted NLL."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from towerpipe.training.losses import class_balanced_weights, effective_number, weighted_nll


def test_effective_number_by_hand():
    # (1 - 0.9**2) / (1 - 0.9) = 0.19 / 0.1 = 1.9 ; n = 1 -> 1
    np.testing.assert_allclose(effective_number([2, 1, 0], 0.9), [1.9, 1.0, 0.0])


def test_weights_by_hand():
    counts = [1000, 10]
    e_neg = (1 - 0.999**1000) / 0.001  # 632.3046
    e_pos = (1 - 0.999**10) / 0.001  # 9.95512
    w = np.array([1 / e_neg, 1 / e_pos])
    w = w / w.sum() * 2
    np.testing.assert_allclose(class_balanced_weights(counts, 0.999), w)
    np.testing.assert_allclose(class_balanced_weights(counts, 0.999), [0.0310, 1.9690], atol=5e-4)
    assert class_balanced_weights(counts, 0.999).sum() == pytest.approx(2.0)


def test_beta_limits():
    # beta = 0.9: E_n ~ 10 for both classes -> (almost) no reweighting
    np.testing.assert_allclose(class_balanced_weights([80000, 700], 0.9), [1.0, 1.0], atol=1e-9)
    # larger beta moves towards inverse frequency
    w3 = class_balanced_weights([80000, 700], 0.999)
    w4 = class_balanced_weights([80000, 700], 0.9999)
    assert w3[1] < w4[1]
    with pytest.raises(ValueError):
        effective_number([1], 1.0)


def test_weighted_nll_matches_manual():
    logp = torch.log_softmax(torch.tensor([[2.0, 0.0], [0.0, 1.0], [1.0, 1.0]]), dim=-1)
    t = torch.tensor([0, 1, 1])
    w = torch.tensor([0.5, 1.5])
    manual = -(0.5 * logp[0, 0] + 1.5 * logp[1, 1] + 1.5 * logp[2, 1]) / (0.5 + 1.5 + 1.5)
    assert float(weighted_nll(logp, t, w)) == pytest.approx(float(manual))
