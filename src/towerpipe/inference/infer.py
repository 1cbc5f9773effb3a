"""Gated sliding-window inference: a tower probability for every core point of a tile.

The method of Carós et al. (2022, sec. 3.2): each 40 × 40 m window of the tile's
model-input points (not ground, not noise) is sampled to ``n_points`` with the
constrained sampler, the classifier decides whether a tower is in it, and only
windows at or above the gate threshold go through the segmenter, on **all** their
points. Windows below the gate are background and cost one classifier pass.

With ``windows: candidates`` and a shape verifier, a **shape gate** comes first: a window
whose peak stands on an object the verifier scores below ``shape_gate``
(:func:`towerpipe.towers.shape.peak_scores`: a crown, a roof) is background without a
classifier pass. A forest gives a thousand peaks a km², and the classifier's gate, low
enough to let real towers through, passed 40 % of them to the segmenter.

With ``secondary_radius`` > 0 the peaks within that radius that are not peaks within
:data:`~towerpipe.inference.candidates.PEAK_RADIUS` get windows too (a tower among higher
crowns has no peak of its own): they pass the same gates, are segmented only farther than
``PEAK_RADIUS`` from every segmented primary peak, and set the probabilities of the points
within ``secondary_reach`` of their centre only.

With ``stem_gap`` > 0 the columns farther than that from every peak get windows too
(:func:`~towerpipe.inference.candidates.stem_columns`: the lower tower of two side by side, whose
neighbour's crossarms pass over its top): they pass the shape gate but not the classifier, are
segmented after the peak windows only where these painted a tower beside them
(:func:`~towerpipe.inference.candidates.stems_beside`), and set the probabilities within
``stem_reach`` of their centre only.

Windows overlap (``stride < window``); the probabilities of a point from the
segmented windows that contain it are combined with ``max`` (default) or ``mean``.
A point that no segmented window contains has probability 0 and is not written.

With ``tta`` > 1 each segmented window also goes through the segmenter turned about its
centre (:func:`towerpipe.inference.views.segment_views`); two probabilities are written
per point: the window as it is (``prob_single``, on which towers are found) and the mean
over the views (``prob``, which picks a tower's points and becomes ``TowerProbability``).

Only the tile's **core** points are written (each point of a zone lies in exactly one
tile core); buffer points give context to the windows that reach into them.

Determinism
    Each window's sampler draws from its own generator seeded from ``seed`` and the
    window's *global* grid indices (:mod:`towerpipe.inference.windows`,
    :mod:`towerpipe.inference.candidates`), and a window's points are listed in canonical
    ``(block_id, point_index)`` order. The result therefore
    depends neither on the order in which windows are processed, nor on the batch
    size, nor on how the tile stores its points; a window seen by two neighbouring
    tiles gets identical inputs in both.

Memory
    Classifier inputs are built one batch at a time (``(batch_size, n_points, C)``
    float32); the segmenter takes one window at a time and chunks internally; per
    point the tile keeps one float32 accumulator (two with ``tta`` > 1) and one
    uint16 count.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from towerpipe.config import InferenceConfig
from towerpipe.errors import ConfigError, ModelError
from towerpipe.inference.candidates import (
    STEM_PAINTED,
    CandidateWindows,
    candidate_windows,
    segmented_windows,
    stems_beside,
)
from towerpipe.inference.compat import BundleLike, check_model_compatibility, model_info
from towerpipe.inference.views import check_views, segment_views
from towerpipe.inference.windows import TileWindows, classifier_pass, sliding_windows, window_gates
from towerpipe.inference.wire_mask import classified_wire, overhead_wires, wire_source
from towerpipe.io.predictions import save_pred
from towerpipe.io.tiles import Tile, load_tile
from towerpipe.progress import Progress, peak_rss_mb

if TYPE_CHECKING:
    from towerpipe.towers.shape import ShapeVerifier

__all__ = ["infer_tile", "predict_tile", "window_rng"]

_COMBINE = ("max", "mean")
#: How a tile's windows are laid: centred on height peaks, or the paper's sliding grid.
WINDOW_MODES = ("candidates", "grid")


def window_rng(seed: int, kx: int, ky: int) -> np.random.Generator:
    """The sampler's generator of window ``(kx, ky)`` (global grid indices)."""
    return np.random.default_rng(
        np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(kx) & 0xFFFFFFFF, int(ky) & 0xFFFFFFFF])
    )


def predict_tile(
    tile: Tile,
    bundle: BundleLike,
    settings: InferenceConfig,
    *,
    seed: int = 0,
    verifier: ShapeVerifier | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Tower probabilities of a tile's core points (in memory; see :func:`infer_tile`).

    ``settings.windows``: ``"grid"`` slides windows on a ``stride`` grid and skips those whose
    highest point is below ``min_height`` (the paper's); ``"candidates"`` centres one window
    on each height peak of at least ``min_height`` (:func:`towerpipe.inference.candidates.candidate_windows`)
    and, with a ``verifier`` and ``settings.shape_gate`` > 0, skips those whose peak object
    scores below it (:func:`towerpipe.towers.shape.peak_scores`).

    Returns
    -------
    arrays
        Prediction arrays (:data:`towerpipe.io.predictions.PRED_ARRAYS`) of the core points
        inside at least one segmented window, in tile order; points the input classifies as
        wire (:data:`towerpipe.classes.WIRE`) have probability 0, so reprocessing a
        classified block gives the same towers, and so have, in a tile where the input
        classifies no point as wire (:func:`wire_source`), those the wire detector finds.
    stats
        ``windows_total``, ``windows_passed_gate``, ``windows_segmented``, ``wire_source``,
        ``windows_empty`` (windows with fewer than ``min_points`` points),
        ``windows_prefiltered`` (windows whose highest point is below ``min_height``,
        background without a classifier pass), ``windows_shape_gated`` (windows whose peak
        object the shape gate judged background),
        ``gate_threshold``, ``combine``, ``points_core``, ``points_model_input_core``,
        ``points_predicted``, ``timings`` (s), ``window_probs`` (list of
        ``[kx, ky, p]`` for the windows that passed the gate) and ``window_gates``
        (:func:`towerpipe.inference.windows.window_gates`: what the gates made of every window with something tall in it).
    """
    from towerpipe.model import features, sampling

    window, stride, windows, gate, combine = (
        settings.window,
        settings.stride,
        settings.windows,
        settings.gate,
        settings.combine,
    )
    batch_size, min_points, min_height, tta = (
        settings.batch_size,
        settings.min_points,
        settings.min_height,
        settings.tta,
    )
    if combine not in _COMBINE:
        raise ConfigError(f"infer.combine must be one of {_COMBINE}, got {combine!r}")
    if windows not in WINDOW_MODES:
        raise ConfigError(f"inference.windows must be one of {WINDOW_MODES}, got {windows!r}")
    if not (0.0 <= gate <= 1.0):
        raise ConfigError(f"infer.gate must be in [0, 1], got {gate}")
    if batch_size < 1:
        raise ConfigError(f"infer.batch_size must be >= 1, got {batch_size}")
    check_views(tta)  # before the classifier pass, not at the first segmented window
    if np.asarray(tile.arrays["model_input"], dtype=bool).any():  # nothing to predict needs no features
        check_model_compatibility(tile.meta, bundle)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()

    arrays = tile.arrays
    core = np.asarray(arrays["core"], dtype=bool)
    mi = np.flatnonzero(np.asarray(arrays["model_input"], dtype=bool))
    canon = np.lexsort((arrays["point_index"][mi], arrays["block_id"][mi]))
    hag = arrays["hag"]
    wires = tree = None
    if windows == "candidates":
        from towerpipe.towers.kdtree import tile_tree

        floor = 0.0 if min_height is None else min_height
        wires = overhead_wires(arrays, mi, floor)
        # the windows' and the shape gate's (both count or sort what it finds)
        tree = tile_tree(np.c_[arrays["x"][mi], arrays["y"][mi]])
        ws: TileWindows | CandidateWindows = candidate_windows(
            arrays["x"][mi],
            arrays["y"][mi],
            hag[mi],
            core[mi],
            window=window,
            min_height=floor,
            min_points=max(int(min_points), 1),
            canonical_order=canon,
            exclude=wires,
            tree=tree,
            secondary_radius=settings.secondary_radius,
            secondary_reach=settings.secondary_reach,
            stem_gap=settings.stem_gap,
            stem_reach=settings.stem_reach,
        )
        n_all = len(ws)
        reach, stem = ws.reach, ws.stem
    else:
        all_windows = sliding_windows(
            arrays["x"][mi],
            arrays["y"][mi],
            core[mi],
            window=window,
            stride=stride,
            min_points=1,
            canonical_order=canon,
        )
        ws = all_windows.select(all_windows.counts >= max(int(min_points), 1))
        n_all = len(all_windows)
        reach = np.full(len(ws), np.inf)  # every grid window sets all its points
        stem = np.zeros(len(ws), bool)
    fmeta = features.tile_feature_meta(arrays, tile.meta)
    timings["windows"] = time.perf_counter() - t0

    # --- optional height pre-filter: a window with nothing tall holds no tower -------
    n_win = len(ws)
    if min_height is not None and windows == "grid":
        tall = np.fromiter((hag[mi[ws.indices(i)]].max() >= min_height for i in range(n_win)), bool, n_win)
    else:
        tall = np.ones(n_win, dtype=bool)
    todo = np.flatnonzero(tall)
    timings["prefilter"] = time.perf_counter() - t0 - timings["windows"]

    # --- shape gate: the object at a candidate's peak is a crown or a roof -----------
    n_tall = len(todo)
    tall_windows = todo
    win_shape = np.full(n_win, np.nan)  # the shape gate's score of each window it judged
    ts = time.perf_counter()
    by_shape = windows == "candidates" and verifier is not None  # the grid's windows have no peak
    if by_shape and settings.shape_gate > 0 and n_tall:
        from towerpipe.towers.shape import peak_objects, peak_scores

        px, py, ph = arrays["x"][mi], arrays["y"][mi], hag[mi]
        objects = peak_objects(ws.centers[todo], px, py, ph, exclude=wires, tree=tree)
        win_shape[todo] = peak_scores(verifier, objects, px, py, ph)
        todo = todo[win_shape[todo] >= settings.shape_gate]
    timings["shape_gate"] = time.perf_counter() - ts
    # a stem candidate is judged by where it stands (beside a tower the peak windows paint), not by the classifier
    stems, todo = todo[stem[todo]], todo[~stem[todo]]

    # --- classifier gate, one batch at a time ---------------------------------------
    n_pts = int(bundle.n_points)
    win_prob = np.zeros(n_win, dtype=np.float32)
    t_sample = t_clf = 0.0
    buf: np.ndarray | None = None
    n_todo = len(todo)
    loaded_s = float(getattr(bundle, "load_s", 0.0))
    what = f"infer {tile.meta.get('block', '?')}/{tile.meta.get('tile', '?')}"
    progress = Progress(f"{what}: classifier", n_todo, "windows")
    for b0 in range(0, n_todo, batch_size):
        ta = time.perf_counter()
        b1 = min(b0 + batch_size, n_todo)
        for j, i in enumerate(todo[b0:b1]):
            idx = mi[ws.indices(i)]
            kx, ky = ws.keys[i]
            s = sampling.constrained_sample(hag[idx], n=n_pts, rng=window_rng(seed, kx, ky))
            f = features.window_features(arrays, idx, ws.center(i), bundle.feature_set, fmeta, s)
            if buf is None:
                buf = np.empty((min(batch_size, n_todo), n_pts, f.shape[1]), dtype=np.float32)
            buf[j] = f
        tb = time.perf_counter()
        win_prob[todo[b0:b1]] = np.asarray(bundle.classify(buf[: b1 - b0]), dtype=np.float32).reshape(-1)
        t_clf += time.perf_counter() - tb
        t_sample += tb - ta
        progress.update(b1 - b0)
    progress.close()
    # a lazily loaded bundle loads its networks in its first classify call: not the classifier's time
    timings["load_networks"] = float(getattr(bundle, "load_s", 0.0)) - loaded_s
    t_clf -= timings["load_networks"]
    timings["sample_features"] = t_sample
    timings["classify"] = t_clf

    # --- segmenter on all points of the windows that passed the gate ----------------
    shape_of = win_shape[todo] if by_shape else None
    ok = classifier_pass(win_prob[todo], shape_of, gate, settings.gate_sure, settings.unsure_shape)
    if by_shape and settings.shape_pass is not None:  # the verifier sure of the peak's object: segmented anyway
        ok |= win_shape[todo] >= settings.shape_pass
    passed = todo[ok]
    if windows == "candidates":
        passed = segmented_windows(ws.centers, reach, passed)
    acc = np.zeros(len(mi), dtype=np.float32)
    acc1 = acc if tta == 1 else np.zeros(len(mi), dtype=np.float32)  # the single view
    cnt = np.zeros(len(mi), dtype=np.uint16)
    t_seg = t_comb = 0.0
    progress = Progress(f"{what}: segmenter", len(passed), "windows")

    def segment(i: int) -> None:
        nonlocal t_seg, t_comb
        ta = time.perf_counter()
        local = ws.indices(i)
        idx = mi[local]
        f = features.window_features(arrays, idx, ws.center(i), bundle.feature_set, fmeta)
        p1, p = segment_views(bundle, f, tta)
        if p.shape != (len(idx),):
            raise ModelError(f"model {bundle.name!r}: segment returned {p.shape} for {len(idx)} points")
        tb = time.perf_counter()
        if np.isfinite(reach[i]):  # a secondary or stem candidate's window: its centre's points only
            cx, cy = ws.center(i)
            near = np.hypot(arrays["x"][idx] - cx, arrays["y"][idx] - cy) <= reach[i]
            local, p, p1 = local[near], p[near], p1[near]
        for a, q in ((acc, p), (acc1, p1)) if tta > 1 else ((acc, p),):
            if combine == "max":
                a[local] = np.maximum(a[local], q)
            else:
                a[local] += q
        cnt[local] += 1
        t_comb += time.perf_counter() - tb
        t_seg += tb - ta
        progress.update()

    for i in passed:
        segment(int(i))
    if len(stems) and len(passed):  # then the stems beside what the peak windows painted
        painted = (acc1 / np.maximum(cnt, 1) if combine == "mean" else acc1) >= STEM_PAINTED[1]
        near = stems_beside(ws.centers[stems], np.c_[arrays["x"][mi[painted]], arrays["y"][mi[painted]]])
        progress.total += int(near.sum())
        for i in stems[near]:
            segment(int(i))
        passed = np.sort(np.concatenate([passed, stems[near]]))
    progress.close()
    timings["segment"] = t_seg
    timings["combine"] = t_comb

    seen = cnt > 0
    if combine == "mean":
        acc[seen] /= cnt[seen]
        if tta > 1:
            acc1[seen] /= cnt[seen]
    sel_local = np.flatnonzero(seen & core[mi])
    sel = mi[sel_local]
    out = {
        "block_id": arrays["block_id"][sel],
        "point_index": arrays["point_index"][sel],
        "x": arrays["x"][sel],
        "y": arrays["y"][sel],
        "z": arrays["z"][sel],
        "hag": arrays["hag"][sel],
        "prob": np.clip(acc[sel_local], 0.0, 1.0).astype(np.float32),
        "prob_single": np.clip(acc1[sel_local], 0.0, 1.0).astype(np.float32),
    }
    # what the delivery classifies as wire is never tower; in a tile where it classifies no point as
    # wire (a flight delivered without a wire class), what the wire detector finds is never tower
    # either: the segmenter paints pieces of conductor, and they were reported as towers
    source = wire_source(arrays, mi)
    if source == "detected" and len(sel):
        if wires is None:  # grid windows: the detector has not run (the conductor layer's floor)
            from towerpipe.towers.wires import WIRE_MIN_HAG_M

            wires = overhead_wires(arrays, mi, WIRE_MIN_HAG_M)
        wire = wires[sel_local]
    else:
        wire = classified_wire(arrays, sel)
    out["prob"][wire] = 0.0
    out["prob_single"][wire] = 0.0
    timings["total"] = time.perf_counter() - t0
    stats = {
        "windows_total": int(n_win),
        "windows_empty": int(n_all - n_win),
        "windows_mode": windows,
        "wire_source": source,
        "windows_prefiltered": int(n_win - n_tall),
        "windows_shape_gated": int(n_tall - n_todo - len(stems)),
        "shape_gate": float(settings.shape_gate) if by_shape else None,
        "windows_classified": int(n_todo),
        "windows_passed_gate": int(len(passed)),
        "windows_segmented": int(len(passed)),
        "gate_threshold": float(gate),
        "gate_sure": float(settings.gate_sure),
        "unsure_shape": float(settings.unsure_shape) if by_shape else None,
        "combine": combine,
        "tta": int(tta),
        "window": float(window),
        "stride": float(stride),
        "min_points": int(min_points),
        "min_height": None if min_height is None else float(min_height),
        "seed": int(seed),
        "points_core": int(core.sum()),
        "points_model_input_core": int(core[mi].sum()),
        "points_predicted": int(len(sel)),
        "timings": timings,
        "windows_per_s_classify": float(n_todo / (t_sample + t_clf)) if n_todo and (t_sample + t_clf) > 0 else None,
        "window_probs": [[int(ws.keys[i, 0]), int(ws.keys[i, 1]), float(win_prob[i])] for i in passed if not stem[i]],
        "window_gates": window_gates(
            np.array([ws.center(int(i)) for i in tall_windows]),
            win_shape[tall_windows],
            np.where(np.isin(tall_windows, todo), win_prob[tall_windows], np.nan),  # classified or not
            np.isin(tall_windows, passed),
        ),
    }
    return out, stats


def infer_tile(
    tile_path: str | os.PathLike[str],
    model: str | os.PathLike[str] | BundleLike | None,
    out_path: str | os.PathLike[str],
    settings: InferenceConfig,
    *,
    seed: int = 0,
    choice: Mapping[str, Any] | str | os.PathLike[str] | None = None,
    verifier: ShapeVerifier | str | os.PathLike[str] | None = None,
    tile: Tile | None = None,
) -> dict[str, Any]:
    """Run gated window inference on one tile file and write its prediction file.

    Parameters
    ----------
    tile_path
        Tile file (:mod:`towerpipe.io.tiles`).
    model
        A model bundle, or the path of a checkpoint directory (read as a
        :class:`towerpipe.model.lazy.LazyBundle`: a tile with no window to classify never
        loads the networks); ``None``: the model of ``choice``.
    out_path
        Prediction file (:mod:`towerpipe.io.predictions`), written atomically.
    settings
        The ``inference`` section (:class:`towerpipe.config.InferenceConfig`):

        - ``window``, ``stride``: window side and step (m); ``window - stride`` is the overlap;
        - ``gate``: windows whose classifier probability is below it are background;
        - ``combine``: ``"max"`` or ``"mean"`` over the segmented windows containing a point;
        - ``batch_size``: windows per classifier call;
        - ``min_points``: windows with fewer model-input points are skipped as empty;
        - ``min_height``: pre-filter (not in the paper): windows whose highest model-input
          point is below this HAG (m) are background without a classifier pass (the shipped
          8 m sits under what a flight shows of a 10 m tower's top), skipping open land and low
          vegetation at no model cost. ``None``: every window is classified;
        - ``tta``: views of each segmented window averaged (:func:`towerpipe.inference.views.segment_views`): 1, 2, 4 or 8;
        - ``windows``: ``"candidates"`` (windows centred on height peaks) or ``"grid"``
          (:func:`predict_tile`);
        - ``shape_gate``: with candidate windows and a ``verifier``, windows whose peak
          object scores below this are background without a classifier pass (0: none).
    seed
        Base seed of the per-window samplers.
    choice
        The zone's model choice (:func:`towerpipe.model.choice.choose_model`, or its JSON
        file): recorded as ``model.choice``; a block it lists as incompatible fails here
        with the message naming the config key.
    verifier
        The shape verifier of the shape gate, or its ``towers.verifier`` spec
        (:func:`towerpipe.towers.shape.load_verifier`; ``"none"``: no shape gate).
    tile
        The tile as :func:`towerpipe.io.tiles.load_tile` read it from ``tile_path``, every
        column (a job that reads it for other work too); read here if not given.

    Returns
    -------
    dict
        The prediction file's ``meta`` (see :mod:`towerpipe.io.predictions`) plus
        ``points_predicted``, ``windows_empty`` and ``windows_per_s_classify``.
    """
    t0 = time.perf_counter()
    if isinstance(choice, (str, os.PathLike)):
        from towerpipe.model.choice import read_choice

        choice = read_choice(choice)
    model_path = None
    if model is None:  # the zone's chosen model, read from its choice
        if not isinstance(choice, Mapping) or not choice.get("path"):
            raise ConfigError(f"{tile_path}: no model given and no model choice to read it from")
        model = choice["path"]
    if isinstance(model, (str, os.PathLike)):  # the networks load on the first window that needs them
        from towerpipe.model.lazy import LazyBundle

        model_path = model
        bundle = LazyBundle(model)
    else:
        bundle = model
    t_model = time.perf_counter() - t0
    tile = load_tile(tile_path) if tile is None else tile
    t_load = time.perf_counter() - t0 - t_model
    if choice is not None and np.asarray(tile.arrays["model_input"], dtype=bool).any():
        from towerpipe.model.choice import incompatibility_error

        msg = incompatibility_error(choice, str(tile.meta.get("block")))
        if msg:
            raise ModelError(msg)
    if isinstance(verifier, (str, os.PathLike)):
        from towerpipe.towers.shape import load_verifier

        verifier = load_verifier(verifier) if settings.shape_gate > 0 else None
    arrays, stats = predict_tile(tile, bundle, settings, seed=seed, verifier=verifier)
    timings = {"load_model": t_model, "load_tile": t_load, **stats.pop("timings")}
    meta = {k: tile.meta.get(k) for k in ("zone", "block", "tile", "blocks", "crs_wkt", "core_bounds")}
    meta["model"] = model_info(bundle, model_path)
    meta["shape_verifier"] = verifier.name if verifier is not None else None
    if choice is not None:
        meta["model"]["choice"] = {k: choice.get(k) for k in ("mode", "key", "reason", "valid_attributes")}
    meta.update(stats)
    tw = time.perf_counter()
    meta["timings"] = timings
    meta["peak_rss_mb"] = peak_rss_mb()
    save_pred(out_path, arrays, meta)
    timings["write"] = time.perf_counter() - tw
    timings["total"] = time.perf_counter() - t0
    return meta
