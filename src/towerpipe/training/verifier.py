"""Training the shape verifier (:class:`towerpipe.towers.shape.ShapeVerifier`).

The examples are *objects* of the training zones' tiles, described as the towers step
describes a candidate (:func:`towerpipe.towers.shape.object_points`: the model-input points
within 1 m of a footprint):

* **towers**: each labelled tower (class 15, components within 2.5 m, at least 20 points,
  10 m high) seen through the footprint of a random 50-100 % of its points, as a segmenter
  that finds part of a tower gives it;
* **other tall objects**: at each height peak of the points that are not tower or wire
  (:func:`towerpipe.inference.candidates.height_peaks`, at least 10 m, more than 12 m from a
  tower), the footprint of the points within 2.5-8 m of the peak: the crowns, roofs, cranes
  and masts where inference puts its windows;
* **the shape gate's view** (``peak_view``, off by default): at each candidate peak of the tile, found as the
  inference finds them (overhead wires left out, :func:`towerpipe.inference.wire_mask.overhead_wires`),
  the object the shape gate cuts there (:func:`towerpipe.towers.shape.peak_objects`: whatever
  stands within 5 m of the peak, the bushes and crowns at a tower's foot included): a tower
  if the peak is within ``peak_tower_m`` of one, another object if it is more than
  ``peak_clearance_m`` from every tower. Measured (docs/model.md, the shape verifier): it
  lets the gate keep two more generated towers of the calibration zones but judges the
  real families left out of training worse, so the shipped verifier is trained without it.

Each object is seen ``copies`` times, each time thinned to a density drawn log-uniformly in
``density_range`` pts/m² (as the training windows are); a share ``occlusion`` of the copies
also loses points as a flight loses them (:func:`occlude`: the lower part thinned under a
canopy or in a scan shadow, or one side of the object unseen), towers and others alike, so
that missing points say nothing about the label. A tower's family (synthetic, ts40k,
uav, utility) comes from the zone's truth, so a verifier can be trained *without* one family
for the leave-one-source-out benchmark. The network is small (two hidden layers of 32)
and trains in seconds with Adam on the class-balanced logistic loss; it is written as JSON
(``verifier.json``: descriptor normalisation, weights, card) and read with numpy.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from towerpipe.towers.shape import (
    DESCRIPTOR_NAMES,
    PEAK_OBJECT_MIN_HAG,
    VERIFIER_FILE,
    ShapeVerifier,
    object_points,
    peak_objects,
    shape_descriptor,
)

__all__ = ["DEFAULT_VERIFIER_CONFIG", "collect_objects", "fit_verifier", "occlude", "train_verifier"]

log = logging.getLogger(__name__)

#: The recipe (``training.verifier`` in config/models.yaml overrides it).
DEFAULT_VERIFIER_CONFIG: dict[str, Any] = {
    "copies": 2,
    "density_range": [2.0, 30.0],
    "min_tower_points": 20,
    "min_height": 10.0,
    "tower_link_m": 2.5,
    "tower_keep": [0.5, 1.0],
    "peak_radius_m": [2.5, 8.0],
    "peak_clearance_m": 12.0,
    "peak_view": False,
    "peak_tower_m": 6.0,
    "occlusion": 0.0,
    "hidden": 32,
    "epochs": 300,
    "lr": 0.01,
    "weight_decay": 0.001,
    "val_fraction": 0.2,
    "seed": 0,
    "exclude_families": [],
}

_KINDS = {3: "tree", 4: "tree", 5: "tree", 6: "building"}


def occlude(x: np.ndarray, y: np.ndarray, hag: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Which points of an object a flight still sees when part of it is hidden.

    One of two losses, drawn at random: the lower part thinned (a canopy or a scan shadow at
    the object's foot: the share kept rises linearly from 5-50 % at the ground to all at the
    top), or one side unseen (the points beyond a random vertical plane near the object's axis
    dropped with a probability of 50-100 %).

    Returns
    -------
    numpy.ndarray
        Bool mask of the points kept.
    """
    u = rng.random(len(x))
    if rng.random() < 0.5:
        floor = rng.uniform(0.05, 0.5)
        rel = np.clip(np.asarray(hag, np.float64) / max(float(np.max(hag)), 1e-6), 0.0, 1.0)
        return u < floor + (1.0 - floor) * rel
    angle = rng.uniform(0.0, 2.0 * np.pi)
    side = (x - x.mean()) * np.cos(angle) + (y - y.mean()) * np.sin(angle)
    reach = max(float(np.abs(side).max()), 1e-6)
    return ~((side > rng.uniform(-0.2, 0.5) * reach) & (u < rng.uniform(0.5, 1.0)))


def _tile_objects(path: str, truth: Any, cfg: Mapping[str, Any], seed: Sequence[int]) -> list[dict[str, Any]]:
    """The objects of one tile: ``{"label", "kind", "view", "block", "descriptor"}`` dicts."""
    from scipy.spatial import cKDTree

    from towerpipe import classes
    from towerpipe.inference.candidates import height_peaks
    from towerpipe.io.tiles import load_tile
    from towerpipe.towers.coverage import tile_density
    from towerpipe.towers.hull import plan_hull
    from towerpipe.training.dataset import nearest_families, tower_instances

    rng = np.random.default_rng(list(seed))
    tile = load_tile(path)
    a = tile.arrays
    keep = np.asarray(a["model_input"], bool) & (a["hag"] >= 0.5)
    x, y = a["x"][keep], a["y"][keep]
    hag, cls = a["hag"][keep].astype(np.float64), a["classification"][keep]
    xmin, ymin, xmax, ymax = (float(v) for v in tile.meta["core_bounds"])
    density = tile_density(tile.meta)
    block = f"{tile.meta.get('zone', '')}/{tile.meta.get('block', Path(path).parent.name)}"
    out: list[dict[str, Any]] = []
    if len(x) == 0:
        return out
    lo, hi = (float(v) for v in cfg["density_range"])

    def add_points(label: int, kind: str, view: str, px: np.ndarray, py: np.ndarray, ph: np.ndarray) -> None:
        thin = min(1.0, float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) / max(density, 1e-9))
        seen = rng.random(len(px)) < thin
        # no draw at all without occlusion: the default recipe keeps the random stream (and the
        # weights) of the shipped verifier
        if float(cfg["occlusion"]) > 0 and rng.random() < float(cfg["occlusion"]):
            seen &= occlude(px, py, ph, rng)
        if seen.sum() >= 10:
            desc = shape_descriptor(px[seen], py[seen], ph[seen])
            out.append({"label": label, "kind": kind, "view": view, "block": block, "descriptor": desc})

    def add(label: int, kind: str, region_xy: np.ndarray) -> None:
        idx = object_points(plan_hull(region_xy), x, y)
        add_points(label, kind, "footprint", x[idx], y[idx], hag[idx])

    def in_core(cx: float, cy: float) -> bool:
        return xmin <= cx < xmax and ymin <= cy < ymax

    xy = np.c_[x, y]
    tw = np.flatnonzero(cls == classes.TOWER)
    centres = []
    for comp in tower_instances(np.c_[x[tw], y[tw], hag[tw]], float(cfg["tower_link_m"]), int(cfg["min_tower_points"])):
        idx = tw[comp]
        cx, cy = float(x[idx].mean()), float(y[idx].mean())
        centres.append((cx, cy))
        if not in_core(cx, cy) or hag[idx].max() < float(cfg["min_height"]):
            continue
        family = str(nearest_families(np.array([[cx, cy]]), truth)[0])
        for _ in range(int(cfg["copies"])):
            part = idx[rng.random(idx.size) < rng.uniform(*cfg["tower_keep"])]
            add(1, family, xy[part if part.size >= 5 else idx])
    other = ~np.isin(cls, (classes.TOWER, *classes.WIRE))
    _, peaks, _ = height_peaks(x[other], y[other], hag[other], min_height=float(cfg["min_height"]))
    towers = cKDTree(np.asarray(centres)) if centres else None
    low = np.flatnonzero(other & (hag >= PEAK_OBJECT_MIN_HAG))  # as the shape gate cuts a peak's object
    near_tree = cKDTree(xy[low]) if low.size else None
    for cx, cy in peaks:
        if not in_core(cx, cy) or near_tree is None:
            continue
        if towers is not None and towers.query([cx, cy])[0] < float(cfg["peak_clearance_m"]):
            continue
        for _ in range(int(cfg["copies"])):
            near = low[near_tree.query_ball_point([cx, cy], rng.uniform(*cfg["peak_radius_m"]))]
            if near.size >= 5:
                add(0, _KINDS.get(int(np.bincount(cls[near]).argmax()), "other"), xy[near])
    if cfg["peak_view"]:
        _peak_view(a, cfg, truth, towers, in_core, add_points)
    return out


def _peak_view(
    a: Mapping[str, np.ndarray],
    cfg: Mapping[str, Any],
    truth: Any,
    towers: Any,
    in_core: Callable[[float, float], bool],
    add_points: Callable[..., None],
) -> None:
    """The objects the shape gate cuts at the tile's candidate peaks (see the module docstring)."""
    from towerpipe import classes
    from towerpipe.inference.candidates import height_peaks
    from towerpipe.inference.wire_mask import overhead_wires
    from towerpipe.training.dataset import nearest_families

    mi = np.flatnonzero(np.asarray(a["model_input"], bool))
    x, y, hag = a["x"][mi], a["y"][mi], a["hag"][mi].astype(np.float64)
    cls = a["classification"][mi]
    wires = overhead_wires(a, mi, float(cfg["min_height"]))
    _, peaks, _ = height_peaks(x[~wires], y[~wires], hag[~wires], min_height=float(cfg["min_height"]))
    peaks = np.array([p for p in peaks if in_core(*p)]).reshape(-1, 2)
    if not len(peaks):
        return
    dist = towers.query(peaks)[0] if towers is not None else np.full(len(peaks), np.inf)
    is_tower = dist <= float(cfg["peak_tower_m"])
    chosen = is_tower | (dist > float(cfg["peak_clearance_m"]))  # in between: part tower, part not
    peaks, is_tower = peaks[chosen], is_tower[chosen]
    objects = peak_objects(peaks, x, y, hag, exclude=wires)
    families = nearest_families(peaks, truth)
    for i, obj in enumerate(objects):
        if obj is None:
            continue
        if is_tower[i]:
            label, kind = 1, str(families[i])
        elif (cls[obj] == classes.TOWER).any():  # a tower too small to count as one
            continue
        else:
            label, kind = 0, _KINDS.get(int(np.bincount(cls[obj]).argmax()), "other")
        for _ in range(int(cfg["copies"])):
            add_points(label, kind, "peak", x[obj], y[obj], hag[obj])


def collect_objects(
    tile_paths: Sequence[str | os.PathLike[str]],
    config: Mapping[str, Any] | None = None,
    *,
    truth: Mapping[str, str | os.PathLike[str]] | None = None,
    threads: int = 1,
) -> list[dict[str, Any]]:
    """The verifier's examples from labelled tiles (see the module docstring).

    Parameters
    ----------
    tile_paths
        Tile files of the training zones (labels: class 15 towers).
    config
        Overrides of :data:`DEFAULT_VERIFIER_CONFIG`.
    truth
        Zone name -> its ``towers_truth.gpkg``: the real family of each tower.
    threads
        Tiles read in parallel.
    """
    from towerpipe.io.columns import read_meta
    from towerpipe.training.dataset import read_truth

    cfg = {**DEFAULT_VERIFIER_CONFIG, **dict(config or {})}
    truths = {z: read_truth(t) for z, t in (truth or {}).items()}
    paths = sorted(str(p) for p in tile_paths)
    jobs = [(p, truths.get(read_meta(p).get("zone")), cfg, (int(cfg["seed"]), i)) for i, p in enumerate(paths)]
    if threads > 1:
        with cf.ProcessPoolExecutor(threads) as ex:
            parts = list(ex.map(_tile_objects, *zip(*jobs)))
    else:
        parts = [_tile_objects(*j) for j in jobs]
    return [o for part in parts for o in part]


def fit_verifier(desc: np.ndarray, label: np.ndarray, config: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Weights of a :class:`~towerpipe.towers.shape.ShapeVerifier` fitted to descriptors and labels."""
    import torch

    cfg = {**DEFAULT_VERIFIER_CONFIG, **dict(config or {})}
    torch.manual_seed(int(cfg["seed"]))
    desc = np.asarray(desc, np.float64)
    mean, std = desc.mean(axis=0), desc.std(axis=0) + 1e-6
    xt = torch.tensor((desc - mean) / std, dtype=torch.float32)
    yt = torch.tensor(np.asarray(label), dtype=torch.float32)
    hidden = int(cfg["hidden"])
    net = torch.nn.Sequential(
        torch.nn.Linear(desc.shape[1], hidden),
        torch.nn.ReLU(),
        torch.nn.Linear(hidden, hidden),
        torch.nn.ReLU(),
        torch.nn.Linear(hidden, 1),
    )
    opt = torch.optim.Adam(net.parameters(), float(cfg["lr"]), weight_decay=float(cfg["weight_decay"]))
    share = float(yt.mean().clamp(1e-3, 1 - 1e-3))
    weight = torch.where(yt > 0, 0.5 / share, 0.5 / (1 - share))  # classes weighed equally
    for _ in range(int(cfg["epochs"])):
        opt.zero_grad()
        loss = torch.nn.functional.binary_cross_entropy_with_logits(net(xt)[:, 0], yt, weight=weight)
        loss.backward()
        opt.step()
    layers = [m for m in net if isinstance(m, torch.nn.Linear)]
    return {
        "mean": mean.tolist(),
        "std": std.tolist(),
        "layers": [
            [m.weight.detach().double().numpy().tolist(), m.bias.detach().double().numpy().tolist()] for m in layers
        ],
    }


def _rates(score: np.ndarray, label: np.ndarray, kind: np.ndarray, threshold: float = 0.5) -> dict[str, Any]:
    pos, neg = label == 1, label == 0
    out: dict[str, Any] = {
        "towers": int(pos.sum()),
        "tower_recall": float(np.mean(score[pos] >= threshold)) if pos.any() else None,
        "others": int(neg.sum()),
        "false_positive_rate": float(np.mean(score[neg] >= threshold)) if neg.any() else None,
    }
    for k in sorted(set(kind[neg].tolist())):
        out[f"false_positive_rate_{k}"] = float(np.mean(score[neg & (kind == k)] >= threshold))
    return out


def train_verifier(
    tile_paths: Sequence[str | os.PathLike[str]],
    out_dir: str | os.PathLike[str],
    config: Mapping[str, Any] | None = None,
    *,
    truth: Mapping[str, str | os.PathLike[str]] | None = None,
    name: str | None = None,
    threads: int = 1,
) -> Path:
    """Train a shape verifier on labelled tiles and write ``<out_dir>/verifier.json`` and its card.

    A share ``val_fraction`` of the blocks is held out first to report tower recall and
    false-positive rate (at 0.5); the written verifier is then fitted on every block.
    ``exclude_families`` leaves out the towers of those real families (and so trains a
    verifier for the leave-one-source-out benchmark).
    """
    from towerpipe import __version__
    from towerpipe.io.atomic import write_text_atomic

    cfg = {**DEFAULT_VERIFIER_CONFIG, **dict(config or {})}
    t0 = time.perf_counter()
    objects = collect_objects(tile_paths, cfg, truth=truth, threads=threads)
    excluded = set(cfg["exclude_families"])
    objects = [o for o in objects if not (o["label"] == 1 and o["kind"] in excluded)]
    if not any(o["label"] == 1 for o in objects) or all(o["label"] == 1 for o in objects):
        from towerpipe.errors import ConfigError

        raise ConfigError(
            f"train-verifier: {len(list(tile_paths))} tiles give {len(objects)} objects, not both towers and "
            "other tall objects; train on labelled tiles of zones with towers (class 15) and trees"
        )
    desc = np.stack([o["descriptor"] for o in objects])
    label = np.array([o["label"] for o in objects])
    kind = np.array([o["kind"] for o in objects])
    blocks = np.array([o["block"] for o in objects])
    t_collect = time.perf_counter() - t0
    rng = np.random.default_rng(int(cfg["seed"]))
    names = np.array(sorted(set(blocks.tolist())))
    n_val = max(1, int(round(float(cfg["val_fraction"]) * len(names))))
    val_blocks = {str(b) for b in rng.choice(names, n_val, replace=False)}
    val = np.isin(blocks, list(val_blocks))
    held = ShapeVerifier(fit_verifier(desc[~val], label[~val], cfg))
    weights = fit_verifier(desc, label, cfg)
    final = ShapeVerifier(weights)
    out = Path(out_dir)
    name = name or out.name
    card = {
        "name": name,
        "kind": "shape verifier",
        "towerpipe": __version__,
        "descriptor": list(DESCRIPTOR_NAMES),
        "config": cfg,
        "tiles": len(list(tile_paths)),
        "objects": {
            "towers_by_family": {k: int(((label == 1) & (kind == k)).sum()) for k in sorted(set(kind[label == 1]))},
            "others_by_kind": {k: int(((label == 0) & (kind == k)).sum()) for k in sorted(set(kind[label == 0]))},
        },
        "validation": {
            "blocks": sorted(val_blocks),
            **_rates(held.score_descriptors(desc[val]), label[val], kind[val]),
        },
        "training": _rates(final.score_descriptors(desc), label, kind),
        "time_s": {"objects": round(t_collect, 1), "total": round(time.perf_counter() - t0, 1)},
    }
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / VERIFIER_FILE, json.dumps({"card": card, "weights": weights}))
    write_text_atomic(out / "MODEL_CARD.md", _card_markdown(card))
    log.info("%s: %d objects, validation %s", name, len(objects), card["validation"])
    return out


def _card_markdown(card: Mapping[str, Any]) -> str:
    v = card["validation"]
    lines = [
        f"# {card['name']}",
        "",
        "Shape verifier of towerpipe (`towerpipe.towers.shape`): the shape score of the object under",
        "a tower candidate, from its points' positions only (heights above ground on a 0.5 m voxel",
        "grid); the towers step drops candidates below `towers.min_shape_score`.",
        "",
        f"- towerpipe {card['towerpipe']}; trained on {card['tiles']} tiles in {card['time_s']['total']} s",
        f"- towers by family: {json.dumps(card['objects']['towers_by_family'])}",
        f"- other objects by kind: {json.dumps(card['objects']['others_by_kind'])}",
        f"- families left out: {card['config']['exclude_families'] or 'none'}",
        "",
        "## Held-out blocks (score >= 0.5)",
        "",
        "| key | value |",
        "|---|---|",
    ]
    lines += [f"| {k} | {v[k] if not isinstance(v[k], float) else round(v[k], 4)} |" for k in v if k != "blocks"]
    lines += ["", f"Held-out blocks: {', '.join(v['blocks'])}", ""]
    return "\n".join(lines)
