"""Square windows over a tile laid on a sliding grid (the paper's); windows centred on candidate
objects are :mod:`towerpipe.inference.candidates`.

Sliding windows (:func:`sliding_windows`)
-----------------------------------------

Windows are ``window × window`` metres squares laid on a **global** grid of step
``stride``: window ``(kx, ky)`` covers ``[kx·stride, kx·stride + window) ×
[ky·stride, ky·stride + window)``. Anchoring the grid at the CRS origin (not at
the tile) makes a window identical in every tile that sees it, so a point near a
tile edge gets the same windows whichever tile owns it. With the default 40 m
windows and 20 m stride each point lies in up to four windows.

Only windows that contain at least one *core* point are produced (a window may
reach up to ``window`` metres into the buffer; its points include buffer points).
Membership is computed without materialising (window, point) pairs: points are
sorted once into ``stride``-sized grid cells (a stable sort on a canonical order,
see :func:`sliding_windows`), and a window's points are the concatenation of the
slices of its ``ceil(window / stride)²`` cells, filtered on the far edge when
``window`` is not a multiple of ``stride``. Memory is O(points + cells).

Which classified windows go on to the segmenter is :func:`classifier_pass`; what the gates made of
each window (:func:`window_gates`) is recorded in the prediction file's ``meta``, for ``towerpipe trace``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

__all__ = ["TileWindows", "classifier_pass", "sliding_windows", "window_gates"]


@dataclass(frozen=True)
class TileWindows:
    """The non-empty windows of one tile and a way to list their points.

    Attributes
    ----------
    window, stride
        Window side and grid step (m).
    keys
        ``(W, 2)`` int64 global window indices ``(kx, ky)`` in a deterministic order.
    counts
        ``(W,)`` number of points in each window.
    core_counts
        ``(W,)`` number of core points in each window.
    """

    window: float
    stride: float
    keys: np.ndarray
    counts: np.ndarray
    core_counts: np.ndarray
    _x: np.ndarray
    _y: np.ndarray
    _order: np.ndarray
    _cell_start: np.ndarray
    _c0: tuple[int, int]
    _shape: tuple[int, int]

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def cells_per_window(self) -> int:
        """Cells spanned by a window along one axis, ``ceil(window / stride)``."""
        return int(math.ceil(self.window / self.stride - 1e-9))

    def origin(self, i: int) -> tuple[float, float]:
        """Lower-left corner (x, y) of window ``i``."""
        kx, ky = self.keys[i]
        return float(kx * self.stride), float(ky * self.stride)

    def center(self, i: int) -> tuple[float, float]:
        """Centre (x, y) of window ``i``."""
        x0, y0 = self.origin(i)
        return x0 + self.window / 2.0, y0 + self.window / 2.0

    def indices(self, i: int) -> np.ndarray:
        """Indices (into the arrays given to :func:`sliding_windows`) of window ``i``'s points.

        The order is a deterministic function of the window's point set: cells in
        row-major order, and within a cell the canonical order given at construction.
        """
        return self._indices_of_key(int(self.keys[i, 0]), int(self.keys[i, 1]))

    def _indices_of_key(self, kx: int, ky: int) -> np.ndarray:
        m = self.cells_per_window
        nx, ny = self._shape
        ix0, iy0 = kx - self._c0[0], ky - self._c0[1]
        parts = []
        for a in range(max(ix0, 0), min(ix0 + m, nx)):
            lo_c = a * ny + max(iy0, 0)
            hi_c = a * ny + min(iy0 + m, ny)
            if hi_c <= lo_c:
                continue
            lo, hi = self._cell_start[lo_c], self._cell_start[hi_c]
            if hi > lo:
                parts.append(self._order[lo:hi])
        idx = np.concatenate(parts) if parts else np.empty(0, dtype=np.int64)
        if m * self.stride > self.window + 1e-9 and len(idx):
            xe = kx * self.stride + self.window
            ye = ky * self.stride + self.window
            idx = idx[(self._x[idx] < xe) & (self._y[idx] < ye)]
        return idx

    def select(self, mask_or_index: np.ndarray) -> TileWindows:
        """A window set with only the selected windows (same points and grid)."""
        return TileWindows(
            self.window,
            self.stride,
            self.keys[mask_or_index],
            self.counts[mask_or_index],
            self.core_counts[mask_or_index],
            self._x,
            self._y,
            self._order,
            self._cell_start,
            self._c0,
            self._shape,
        )

    def __iter__(self) -> Iterator[np.ndarray]:
        for i in range(len(self)):
            yield self.indices(i)

    def membership_count(self) -> np.ndarray:
        """Number of produced windows containing each point (vectorised; for checks and stats)."""
        n = len(self._x)
        out = np.zeros(n, dtype=np.int32)
        s, w = self.stride, self.window
        cx = np.floor(self._x / s).astype(np.int64)
        cy = np.floor(self._y / s).astype(np.int64)
        keyset = _key_codes(self.keys[:, 0], self.keys[:, 1])
        m = self.cells_per_window
        for i in range(m):
            kx = cx - i
            okx = self._x < kx * s + w
            for j in range(m):
                ky = cy - j
                ok = okx & (self._y < ky * s + w)
                ok &= np.isin(_key_codes(kx, ky), keyset, assume_unique=False)
                out += ok
        return out


def _key_codes(kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    """Pack signed window indices into one int64 code (|k| < 2**31)."""
    return (np.asarray(kx, dtype=np.int64) << 32) + (np.asarray(ky, dtype=np.int64) & 0xFFFFFFFF)


def sliding_windows(
    x: np.ndarray,
    y: np.ndarray,
    core: np.ndarray,
    *,
    window: float = 40.0,
    stride: float = 20.0,
    min_points: int = 1,
    canonical_order: np.ndarray | None = None,
) -> TileWindows:
    """The sliding windows covering every core point, with at least ``min_points`` points.

    Parameters
    ----------
    x, y
        Coordinates (float64) of the candidate points (typically the model-input points
        of a tile, core and buffer).
    core
        Bool mask: the point is owned by the tile. Only windows holding at least one
        core point are produced.
    window
        Window side (m).
    stride
        Grid step (m); ``0 < stride <= window``. ``window - stride`` is the overlap.
    min_points
        Windows with fewer points (core and buffer) are skipped as empty.
    canonical_order
        A permutation of the points giving their canonical order (e.g. by
        ``(block_id, point_index)``), so that a window's point order, and hence its
        seeded sampling, does not depend on how the tile happens to store its points.
        Default: the given order.

    Returns
    -------
    TileWindows
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    core = np.asarray(core, dtype=bool)
    if not (x.shape == y.shape == core.shape and x.ndim == 1):
        raise ValueError("x, y and core must be 1-D arrays of the same length")
    if not (0 < stride <= window):
        raise ValueError(f"need 0 < stride <= window, got stride={stride}, window={window}")
    m = int(math.ceil(window / stride - 1e-9))
    n = len(x)
    if n == 0 or not core.any():
        empty = np.empty((0, 2), dtype=np.int64)
        return TileWindows(
            float(window),
            float(stride),
            empty,
            np.empty(0, np.int64),
            np.empty(0, np.int64),
            x,
            y,
            np.empty(0, np.int64),
            np.zeros(1, np.int64),
            (0, 0),
            (0, 0),
        )

    cx = np.floor(x / stride).astype(np.int64)
    cy = np.floor(y / stride).astype(np.int64)
    c0 = (int(cx.min()), int(cy.min()))
    nx, ny = int(cx.max()) - c0[0] + 1, int(cy.max()) - c0[1] + 1
    cell = (cx - c0[0]) * ny + (cy - c0[1])

    if canonical_order is None:
        base = np.arange(n, dtype=np.int64)
    else:
        base = np.asarray(canonical_order, dtype=np.int64)
        if base.shape != (n,):
            raise ValueError("canonical_order must be a permutation of the points")
    order = base[np.argsort(cell[base], kind="stable")]
    cell_counts = np.bincount(cell, minlength=nx * ny)
    cell_start = np.zeros(nx * ny + 1, dtype=np.int64)
    np.cumsum(cell_counts, out=cell_start[1:])

    exact_cells = abs(m * stride - window) <= 1e-9 * max(window, 1.0)
    if exact_cells:
        keys, counts, core_counts = _windows_from_cells(cell, core, c0, (nx, ny), m)
        keep = counts >= max(int(min_points), 1)
        return TileWindows(
            float(window),
            float(stride),
            keys[keep],
            counts[keep],
            core_counts[keep],
            x,
            y,
            order,
            cell_start,
            c0,
            (nx, ny),
        )

    # general case (window not a multiple of stride): candidate windows from core points
    ccx, ccy = cx[core], cy[core]
    xc, yc = x[core], y[core]
    codes = []
    for i in range(m):
        kx = ccx - i
        okx = xc < kx * stride + window
        for j in range(m):
            ky = ccy - j
            ok = okx & (yc < ky * stride + window)
            codes.append(np.unique(_key_codes(kx[ok], ky[ok])))
    keycodes = np.unique(np.concatenate(codes))
    keys = np.stack([keycodes >> 32, (keycodes & 0xFFFFFFFF).astype(np.int64)], axis=1)
    keys[:, 1] = np.where(keys[:, 1] >= 2**31, keys[:, 1] - 2**32, keys[:, 1])

    ws = TileWindows(
        float(window),
        float(stride),
        keys,
        np.empty(0, np.int64),
        np.empty(0, np.int64),
        x,
        y,
        order,
        cell_start,
        c0,
        (nx, ny),
    )
    counts, core_counts = _window_counts(ws, cx, cy, core)
    keep = counts >= max(int(min_points), 1)
    return TileWindows(
        float(window), float(stride), keys[keep], counts[keep], core_counts[keep], x, y, order, cell_start, c0, (nx, ny)
    )


def _windows_from_cells(
    cell: np.ndarray, core: np.ndarray, c0: tuple[int, int], shape: tuple[int, int], m: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows holding a core point, with point counts, when a window is exactly m×m cells.

    Window counts are m×m box sums of the cell counts (summed-area table), so the cost
    is O(points) for the two bincounts plus O(cells).
    """
    nx, ny = shape
    tot = np.bincount(cell, minlength=nx * ny).reshape(nx, ny)
    cor = np.bincount(cell[core], minlength=nx * ny).reshape(nx, ny)

    def box(grid: np.ndarray) -> np.ndarray:
        # padded grid: window with padded index (a, b) spans cells a-m+1..a, b-m+1..b
        pad = np.zeros((nx + 2 * m - 1, ny + 2 * m - 1), dtype=np.int64)
        pad[m - 1 : m - 1 + nx, m - 1 : m - 1 + ny] = grid
        sat = np.zeros((pad.shape[0] + 1, pad.shape[1] + 1), dtype=np.int64)
        sat[1:, 1:] = pad.cumsum(0).cumsum(1)
        # window whose first cell (relative) is a - (m-1) for a in 0..nx+m-2
        a = np.arange(nx + m - 1)
        b = np.arange(ny + m - 1)
        return (
            sat[a[:, None] + m, b[None, :] + m]
            - sat[a[:, None], b[None, :] + m]
            - sat[a[:, None] + m, b[None, :]]
            + sat[a[:, None], b[None, :]]
        )

    wt, wc = box(tot), box(cor)
    ia, ib = np.nonzero(wc > 0)
    keys = np.stack([ia - (m - 1) + c0[0], ib - (m - 1) + c0[1]], axis=1).astype(np.int64)
    return keys, wt[ia, ib], wc[ia, ib]


def _window_counts(ws: TileWindows, cx: np.ndarray, cy: np.ndarray, core: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and core points per window of ``ws`` (vectorised over points)."""
    s, w = ws.stride, ws.window
    m = ws.cells_per_window
    keycodes = _key_codes(ws.keys[:, 0], ws.keys[:, 1])
    total = np.zeros(len(keycodes), dtype=np.int64)
    ncore = np.zeros(len(keycodes), dtype=np.int64)
    for i in range(m):
        kx = cx - i
        okx = ws._x < kx * s + w
        for j in range(m):
            ky = cy - j
            ok = okx & (ws._y < ky * s + w)
            codes = _key_codes(kx[ok], ky[ok])
            pos = np.searchsorted(keycodes, codes)
            pos = np.minimum(pos, len(keycodes) - 1)
            hit = keycodes[pos] == codes
            total += np.bincount(pos[hit], minlength=len(keycodes))
            ncore += np.bincount(pos[hit], weights=core[ok][hit], minlength=len(keycodes)).astype(np.int64)
    return total, ncore


def window_gates(centers: np.ndarray, shape: np.ndarray, prob: np.ndarray, segmented: np.ndarray) -> dict[str, list]:
    """What the gates made of a tile's windows, for ``towerpipe trace`` to say why a tower was
    never segmented: one entry per window with something at least ``min_height`` in it.

    Parameters
    ----------
    centers
        ``(W, 2)`` the windows' centres (absolute x, y).
    shape, prob
        ``(W,)`` the shape gate's score and the classifier's probability of each (NaN: not
        judged by that gate).
    segmented
        ``(W,)`` bool, whether each was segmented.

    Returns
    -------
    dict
        Columns ``x``, ``y`` (m, to 0.1 m), ``shape``, ``prob`` (4 decimals, ``None`` where not
        judged) and ``segmented``, JSON-able.
    """

    def col(a: np.ndarray, ndigits: int) -> list:
        return [None if not np.isfinite(v) else round(float(v), ndigits) for v in np.asarray(a, np.float64)]

    centers = np.asarray(centers, np.float64).reshape(-1, 2)
    return {
        "x": col(centers[:, 0], 1),
        "y": col(centers[:, 1], 1),
        "shape": col(shape, 4),
        "prob": col(prob, 4),
        "segmented": np.asarray(segmented, dtype=bool).tolist(),
    }


def classifier_pass(
    prob: np.ndarray, shape: np.ndarray | None, gate: float, gate_sure: float, unsure_shape: float
) -> np.ndarray:
    """Which classified windows the classifier's gate passes to the segmenter.

    A window passes when its probability is at least ``gate``. One the classifier is unsure of
    (at least ``gate``, under ``gate_sure``) passes only if its peak object's shape score is at
    least ``unsure_shape``: where neither the classifier nor the shape verifier sees a tower, the
    segmenter is not run (``inference.gate_sure``, ``inference.unsure_shape``).

    Parameters
    ----------
    prob
        ``(W,)`` the classifier's probabilities.
    shape
        ``(W,)`` the shape gate's scores (NaN, or ``None`` for all: not scored, the shape
        condition not applied).
    gate, gate_sure, unsure_shape
        The thresholds; ``unsure_shape`` 0 or ``gate_sure <= gate`` turn the shape condition off.

    Returns
    -------
    numpy.ndarray
        ``(W,)`` bool.
    """
    prob = np.asarray(prob, dtype=np.float64)
    ok = prob >= gate
    if shape is None or unsure_shape <= 0 or gate_sure <= gate:
        return ok
    shape = np.asarray(shape, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # NaN: not scored, never refused here
        refused = (prob < gate_sure) & (shape < unsure_shape)
    return ok & ~refused
