"""``towerpipe train``, ``towerpipe train-verifier`` and ``towerpipe fold-model``: the command
line of :func:`towerpipe.training.train.train_bundle`, :func:`towerpipe.training.verifier.train_verifier`
and :func:`towerpipe.model.bundle.fold_bundle`."""

from __future__ import annotations

import argparse
import glob
from pathlib import Path
from typing import Any

from towerpipe.errors import ConfigError
from towerpipe.model.features import FEATURE_SETS
from towerpipe.training.train import train_bundle


def _paths(patterns: list[str]) -> list[str]:
    paths: list[str] = []
    for pattern in patterns:
        hits = sorted(glob.glob(pattern, recursive=True))
        paths += hits if hits else ([pattern] if Path(pattern).exists() else [])
    if not paths:
        raise ConfigError(f"--tiles {patterns}: no files match")
    return paths


def _verifier_cli(args: argparse.Namespace) -> int:
    from towerpipe.training.verifier import train_verifier

    truth = dict(t.split("=", 1) for t in args.truth)
    config = {"exclude_families": args.exclude_families}
    print(train_verifier(_paths(args.tiles), args.out, config, truth=truth, threads=args.threads))
    return 0


def _fold_cli(args: argparse.Namespace) -> int:
    from towerpipe.model.bundle import fold_bundle

    for path in args.models:
        for name, digest in fold_bundle(path).items():
            print(f"{Path(path) / name}  sha256 {digest}")
    return 0


def read_overrides(path: str | None) -> dict[str, Any]:
    """The training overrides of ``--config``: a YAML or JSON file (YAML reads both), ``{}`` if none."""
    if not path:
        return {}
    import yaml

    config = yaml.safe_load(Path(path).read_text()) or {}
    if not isinstance(config, dict):
        raise ConfigError(f"{path}: the training overrides must be a mapping (e.g. `epochs: 8`)")
    return config


def _cli(args: argparse.Namespace) -> int:
    paths = _paths(args.tiles)
    config = read_overrides(args.config)
    for key in ("epochs", "seed", "time_budget_s", "max_train_windows"):
        if getattr(args, key) is not None:
            config[key] = getattr(args, key)
    out = train_bundle(paths, args.out, args.feature_set, config)
    print(out)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``towerpipe train``, ``train-verifier`` and ``fold-model`` to the command line."""
    p = subparsers.add_parser("train", help="train a classifier + segmenter bundle from labelled tile files")
    p.add_argument(
        "--tiles",
        nargs="+",
        required=True,
        metavar="GLOB",
        help="labelled tile .npz files (globs allowed) or one windows .npz",
    )
    p.add_argument("--out", required=True, help="checkpoint directory to write")
    p.add_argument(
        "--feature-set",
        default="shape",
        choices=sorted(FEATURE_SETS),
        help="the columns the networks read (default: shape, the shipped default; full is the paper's)",
    )
    p.add_argument(
        "--config",
        help="JSON/YAML file of training overrides (key `dataset` for the dataset); without one, the "
        "schema's defaults train the paper's recipe, not the shipped one (config/models.yaml's training.train)",
    )
    p.add_argument("--epochs", type=int)
    p.add_argument("--seed", type=int)
    p.add_argument("--time-budget-s", dest="time_budget_s", type=float, help="per-network wall-clock budget")
    p.add_argument("--max-train-windows", dest="max_train_windows", type=int)
    p.set_defaults(func=_cli)

    v = subparsers.add_parser("train-verifier", help="train the shape verifier of the tower rules from labelled tiles")
    v.add_argument("--tiles", nargs="+", required=True, metavar="GLOB", help="labelled tile .npz files (globs allowed)")
    v.add_argument("--out", required=True, help="verifier directory to write (verifier.json, MODEL_CARD.md)")
    v.add_argument(
        "--truth", nargs="*", default=[], metavar="ZONE=GPKG", help="tower truth of a generated zone (real families)"
    )
    v.add_argument(
        "--exclude-families", nargs="*", default=[], help="real tower families left out (ts40k, uav, utility)"
    )
    v.add_argument("--threads", type=int, default=2)
    v.set_defaults(func=_verifier_cli)

    f = subparsers.add_parser(
        "fold-model", help="add the folded copies (inference without PyTorch) to a model bundle saved without them"
    )
    f.add_argument("models", nargs="+", metavar="DIR", help="model bundle directories")
    f.set_defaults(func=_fold_cli)
