"""Derived random generators: one independent stream per (seed, purpose, index...)."""

from __future__ import annotations

import zlib

import numpy as np


def derive(seed: int, *keys: int | str) -> np.random.Generator:
    """Return a generator for ``seed`` and a path of keys.

    The stream depends only on the seed and the keys, never on what else was
    generated before, so e.g. a block's random pulses do not depend on the order
    in which blocks are produced.
    """
    ints = [int(seed) & 0xFFFFFFFF]
    for k in keys:
        ints.append(zlib.crc32(k.encode()) if isinstance(k, str) else int(k) & 0xFFFFFFFF)
    return np.random.default_rng(np.random.SeedSequence(ints))
