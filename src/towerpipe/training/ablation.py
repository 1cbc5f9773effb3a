"""The ablation study of Carós et al. (2022, Tables 3 and 4) on towerpipe data.

Each row trains a classifier and a segmenter with one choice changed from the
reference (PointNet_L, ``full`` features, constrained sampling, beta = 0.999) and records
classification F1 / precision / recall, segmentation IoU tower / IoU background / mIoU,
training time and peak memory. Rows run one after another, each in a fresh (spawned)
process by default so that its peak RSS is its own. ``ablation.md`` holds both tables
and sentences derived from the numbers; ``ablation.json`` the raw metrics.
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from towerpipe.training.dataset import load_or_build
from towerpipe.training.losses import class_balanced_weights

#: Rows: name -> overrides of the reference configuration.
DEFAULT_ROWS: dict[str, dict[str, Any]] = {
    "reference": {},
    "no_rgb_nir": {"feature_set": "geometry"},
    "random_sampling": {"sampling": "random"},
    "beta_0.9": {"beta": 0.9},
    "beta_0.9999": {"beta": 0.9999},
    "full_pointnet": {"arch": "full"},
}
REFERENCE: dict[str, Any] = {"feature_set": "full", "sampling": "constrained", "beta": 0.999, "arch": "light"}


def _run_row(windows_path: str, config: dict[str, Any]) -> dict[str, Any]:
    """Train both networks for one row (runs in a worker process)."""
    from towerpipe.progress import peak_rss_mb
    from towerpipe.training.train import train_classifier, train_segmenter
    from towerpipe.training.windowset import load_windows

    ws = load_windows(windows_path)
    config = dict(config)
    per_net = {k: dict(config.pop(k, None) or {}) for k in ("classifier", "segmenter")}
    t0 = time.perf_counter()
    _, _, mc = train_classifier(ws, {**config, **per_net["classifier"]})
    _, _, ms = train_segmenter(ws, {**config, **per_net["segmenter"]})
    return {"classifier": mc, "segmenter": ms, "wall_s": time.perf_counter() - t0, "process_peak_rss_mb": peak_rss_mb()}


def _pct(v: float) -> str:
    return f"{100 * v:.1f}"


def _sentence(rows: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Findings computed from the numbers (relative to the reference row)."""
    if "reference" not in rows:
        return []
    ref = rows["reference"]
    f_ref, iou_ref = ref["classifier"]["test"]["f1"], ref["segmenter"]["test"]["iou_tower"]
    labels = {
        "no_rgb_nir": "Dropping RGB and NIR (geometry features)",
        "random_sampling": "Random sampling",
        "beta_0.9": "beta = 0.9",
        "beta_0.9999": "beta = 0.9999",
        "full_pointnet": "The full PointNet",
    }
    out = []
    for name, r in rows.items():
        if name == "reference":
            continue
        df = 100 * (r["classifier"]["test"]["f1"] - f_ref)
        di = 100 * (r["segmenter"]["test"]["iou_tower"] - iou_ref)
        dt = (
            r["classifier"]["train_time_s"]
            + r["segmenter"]["train_time_s"]
            - (ref["classifier"]["train_time_s"] + ref["segmenter"]["train_time_s"])
        )

        def change(d: float, what: str) -> str:
            if abs(d) < 0.05:
                return f"leaves {what} unchanged"
            return f"{'raises' if d > 0 else 'lowers'} {what} by {abs(d):.1f} points"

        out.append(
            f"{labels.get(name, name)} {change(df, 'classification F1')} and "
            f"{change(di, 'segmentation IoU tower')} relative to the reference "
            f"(training time {dt:+.0f} s)."
        )
    best_f1 = max(rows, key=lambda n: rows[n]["classifier"]["test"]["f1"])
    best_iou = max(rows, key=lambda n: rows[n]["segmenter"]["test"]["miou"])
    out.append(f"Best classification F1: `{best_f1}`; best segmentation mIoU: `{best_iou}`.")
    return out


def render_markdown(
    rows: Mapping[str, Mapping[str, Any]], configs: Mapping[str, Mapping[str, Any]], meta: Mapping[str, Any]
) -> str:
    """``ablation.md``: a Table 3-like and a Table 4-like table plus findings."""
    summary = meta.get("summary") or {}
    lines = [
        "# Ablation study (Carós et al. 2022, Tables 3 and 4)",
        "",
        "Each row changes one choice of the reference (PointNet_L, RGB+NIR features, constrained "
        "sampling, beta = 0.999) and trains both networks on the same windows with the same "
        "settings, listed under `configs` in `ablation.json`.",
        "",
        "| split | windows | positive | negative | blocks |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {k} | {v.get('windows')} | {v.get('positive')} | {v.get('negative')} | {len(v.get('blocks', []))} |"
        for k, v in summary.items()
    ]
    lines += [
        "",
        "## Classification (test split)",
        "",
        "| row | model | RGB+NIR | constrained sampling | beta | weights (sum 1) | time [s] | peak RSS [MiB] | precision | recall | F1 |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        c, m = configs[name], r["classifier"]
        w = class_balanced_weights(m["train_counts"], c["beta"])
        lines.append(
            f"| {name} | PointNet{'_L' if c['arch'] == 'light' else ''} | "
            f"{'X' if c['feature_set'] == 'full' else ''} | {'X' if c['sampling'] == 'constrained' else ''} | "
            f"{c['beta']} | [{w[0] / w.sum():.2f}, {w[1] / w.sum():.2f}] | {m['train_time_s']:.0f} | "
            f"{r['process_peak_rss_mb']:.0f} | {_pct(m['test']['precision'])} | {_pct(m['test']['recall'])} | "
            f"{_pct(m['test']['f1'])} |"
        )
    lines += [
        "",
        "## Segmentation (all points of the test positive windows)",
        "",
        "| row | model | RGB+NIR | constrained sampling | weights (sum 1) | time [s] | peak RSS [MiB] | IoU tower | IoU background | mIoU |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        c, m = configs[name], r["segmenter"]
        w = class_balanced_weights(m["train_point_counts"], c["beta"])
        lines.append(
            f"| {name} | PointNet{'_L' if c['arch'] == 'light' else ''} | "
            f"{'X' if c['feature_set'] == 'full' else ''} | {'X' if c['sampling'] == 'constrained' else ''} | "
            f"[{w[0] / w.sum():.2f}, {w[1] / w.sum():.2f}] | {m['train_time_s']:.0f} | "
            f"{r['process_peak_rss_mb']:.0f} | {_pct(m['test']['iou_tower'])} | "
            f"{_pct(m['test']['iou_background'])} | {_pct(m['test']['miou'])} |"
        )
    lines += (
        ["", "## Findings", ""]
        + [f"- {s}" for s in _sentence(rows)]
        + [
            "",
            "Time is training wall time per network on this machine; peak RSS is the peak resident memory of the "
            "process that trained the row (both networks).",
            "",
        ]
    )
    return "\n".join(lines)


def run_ablation(
    dataset_paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    config: Mapping[str, Any] | None = None,
    rows: Mapping[str, Mapping[str, Any]] | None = None,
    subprocess: bool = True,
) -> Path:
    """Run the ablation rows and write ``ablation.md`` and ``ablation.json`` into ``out_dir``.

    Parameters
    ----------
    dataset_paths
        Labelled tile files, or one windows ``.npz``.
    out_dir
        Output directory (the windows are cached there as ``windows.npz`` if built).
    config
        Training overrides shared by every row (see :data:`towerpipe.training.train.DEFAULT_TRAIN_CONFIG`;
        key ``dataset`` for dataset overrides).
    rows
        Row name -> overrides (default :data:`DEFAULT_ROWS`).
    subprocess
        Train each row in a fresh spawned process (own peak-memory figure).

    Returns
    -------
    pathlib.Path
        The ``ablation.md`` file.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    config = dict(config or {})
    ws = load_or_build(dataset_paths, config.pop("dataset", None))
    wpath = out / "windows.npz"
    ws.save(wpath)
    rows = dict(rows or DEFAULT_ROWS)
    if not (ws.meta.get("has_rgb") and ws.meta.get("has_nir")):
        rows = {k: v for k, v in rows.items() if {**REFERENCE, **config, **v}["feature_set"] != "full"}
    configs = {name: {**config, **REFERENCE, **over} for name, over in rows.items()}
    results: dict[str, dict[str, Any]] = {}
    for name, cfg in configs.items():
        if subprocess:
            with cf.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as ex:
                results[name] = ex.submit(_run_row, str(wpath), cfg).result()
        else:
            results[name] = _run_row(str(wpath), cfg)
    (out / "ablation.json").write_text(json.dumps({"configs": configs, "results": results}, indent=1, default=str))
    md = out / "ablation.md"
    md.write_text(render_markdown(results, configs, ws.meta))
    return md
