"""Model cards: what every towerpipe checkpoint records, and their validation.

A card (``model_card.json``, rendered as ``MODEL_CARD.md``) records the feature list,
the normalisation, the sampling, the training data, the metrics, the code version
(``towerpipe.__version__`` and the git commit when available) and a hash of the
training configuration. :func:`read_card` validates a card and raises
:class:`~towerpipe.errors.ModelError` naming the file and the fix.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from towerpipe.errors import ModelError

#: Keys every card must have.
REQUIRED_KEYS: tuple[str, ...] = (
    "name",
    "version",
    "bundle_version",
    "feature_set",
    "features",
    "normalisation",
    "sampling",
    "training_data",
    "metrics",
    "code",
    "config_hash",
)


#: Bundle format version (checkpoint layout and card schema).
BUNDLE_VERSION = 1
#: A bundle's card, and its two networks' checkpoints: the files that make a model directory
#: (the folded copies beside the checkpoints are listed in the card).
CARD_FILE = "model_card.json"
WEIGHT_FILES = ("classifier.pt", "segmenter.pt")
BUNDLE_FILES = (*WEIGHT_FILES, CARD_FILE)
#: Release of the shipped model of each feature set (``models/towerpipe-<set>-v<release>/``):
#: bumped when it is retrained on other data or with another recipe (its card says how).
#: Only models that keep their towers when the tower points take the attributes of their
#: surroundings are shipped (docs/model.md, the attribute-swap check): the colour recipes
#: (``full``, ``rgb``) lost a third to a half of them and are trainable but not shipped.
MODEL_RELEASES = {"geometry": 3, "shape": 3}

#: Environment variable overriding the shipped models directory.
MODELS_ENV = "TOWERPIPE_MODELS"


def repo_root() -> Path | None:
    """The repository root (directory with ``pyproject.toml`` above the package), if any."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "pyproject.toml").is_file() and (parent / "src" / "towerpipe").is_dir():
            return parent
    return None


def models_dir() -> Path:
    """Directory of shipped checkpoints: ``$TOWERPIPE_MODELS``, else ``<repo>/models``."""
    env = os.environ.get(MODELS_ENV)
    if env:
        return Path(env)
    root = repo_root()
    return (root if root is not None else Path.cwd()) / "models"


def default_model_path(feature_set: str = "shape") -> Path:
    """Path of the shipped bundle for ``feature_set``: ``models/towerpipe-<set>-v<release>/``."""
    from towerpipe.model.features import FEATURE_SETS

    if feature_set not in FEATURE_SETS:
        raise ModelError(f"unknown feature set {feature_set!r}; use one of {sorted(FEATURE_SETS)}")
    if feature_set not in MODEL_RELEASES:
        raise ModelError(
            f"no shipped model of feature set {feature_set!r} (shipped: {', '.join(MODEL_RELEASES)}); "
            f"train one (`towerpipe train --feature-set {feature_set}`) and set `inference.model` "
            "to its directory"
        )
    return models_dir() / f"towerpipe-{feature_set}-v{MODEL_RELEASES[feature_set]}"


def sha256(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def config_hash(config: Mapping[str, Any]) -> str:
    """Stable 16-hex-digit hash of a JSON-able configuration (sorted keys)."""
    blob = json.dumps(config, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def code_version() -> dict[str, Any]:
    """``{"towerpipe": __version__, "git_commit": sha or None, "git_dirty": bool or None}``."""
    from towerpipe import __version__

    here = Path(__file__).resolve().parent
    commit: str | None = None
    dirty: bool | None = None
    try:
        r = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10)
        if r.returncode == 0:
            commit = r.stdout.strip()
            s = subprocess.run(
                ["git", "status", "--porcelain", "--untracked-files=no"],
                cwd=here,
                capture_output=True,
                text=True,
                timeout=10,
            )
            dirty = bool(s.stdout.strip()) if s.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        pass
    return {"towerpipe": __version__, "git_commit": commit, "git_dirty": dirty}


def validate_card(card: Mapping[str, Any], path: str | os.PathLike[str] = "model_card.json") -> None:
    """Check a card's keys and consistency; raise :class:`ModelError` naming ``path``."""
    from towerpipe.model.features import FEATURE_SETS

    missing = [k for k in REQUIRED_KEYS if k not in card]
    if missing:
        raise ModelError(
            f"{path}: model card lacks {missing}; the checkpoint is incomplete or from another "
            "tool, retrain with `towerpipe train`"
        )
    if int(card["bundle_version"]) != BUNDLE_VERSION:
        raise ModelError(
            f"{path}: bundle format v{card['bundle_version']} but this towerpipe reads "
            f"v{BUNDLE_VERSION}; retrain or use a matching towerpipe version"
        )
    fs = card["feature_set"]
    if fs not in FEATURE_SETS:
        raise ModelError(f"{path}: unknown feature set {fs!r}; expected one of {sorted(FEATURE_SETS)}")
    if list(card["features"]) != FEATURE_SETS[fs]:
        raise ModelError(
            f"{path}: features {card['features']} differ from this towerpipe's {fs!r} set "
            f"{FEATURE_SETS[fs]}; retrain the model with this version"
        )
    if "n_points" not in card["sampling"]:
        raise ModelError(f"{path}: model card sampling lacks n_points; retrain with `towerpipe train`")


def read_card(directory: str | os.PathLike[str]) -> dict[str, Any]:
    """Read and validate ``<directory>/model_card.json`` (and the weight checksums)."""
    path = Path(directory) / CARD_FILE
    if not path.is_file():
        raise ModelError(f"{path}: missing; not a towerpipe model directory (train one with `towerpipe train`)")
    try:
        card = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ModelError(f"{path}: unreadable model card ({exc}); retrain with `towerpipe train`") from exc
    if not isinstance(card, dict):
        raise ModelError(f"{path}: model card is not a JSON object; retrain with `towerpipe train`")
    validate_card(card, path)
    for name, digest in card.get("files", {}).items():
        f = Path(directory) / name
        if f.is_file() and sha256(f) != digest:
            raise ModelError(
                f"{f}: checksum differs from {path.name}; the weights were modified or "
                "corrupted, copy the checkpoint directory again"
            )
    return card


def bundle_identity(card: Mapping[str, Any]) -> dict[str, Any]:
    """``name``, ``version``, ``feature_set`` and ``n_points`` of a bundle, from its model card."""
    return {
        "name": card["name"],
        "version": str(card["version"]),
        "feature_set": card["feature_set"],
        "n_points": int(card["sampling"]["n_points"]),
    }


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (dict, list)):
        return "`" + json.dumps(v, default=str) + "`"
    return str(v)


#: What each network architecture (``architecture.arch`` of a card) is, in words.
ARCH_WORDS = {
    "light": "PointNet_L, the light PointNet of Carós et al. 2022",
    "full": "PointNet at its full widths",
    "compact": "a compact PointNet: PointNet_L with half its global width (Carós et al. 2022)",
    "edge": "EdgeConv over each point's neighbours",
}


def card_markdown(card: Mapping[str, Any]) -> str:
    """Human-readable ``MODEL_CARD.md`` for a card."""
    arch = (card.get("architecture") or {}).get("arch", "light")
    lines = [
        f"# {card['name']} v{card['version']}",
        "",
        f"Power-tower classifier + segmenter for towerpipe: {ARCH_WORDS.get(arch, arch)} (`{arch}`).",
        "",
        f"- feature set: `{card['feature_set']}` — columns {', '.join(card['features'])}",
        f"- code: towerpipe {card['code'].get('towerpipe')} commit {card['code'].get('git_commit')}",
        f"- config hash: `{card['config_hash']}`",
    ]
    init = card.get("init_from")
    if init:
        what = f"{init.get('name')} v{init.get('version')} ({init.get('path')})" if isinstance(init, Mapping) else init
        lines.append(f"- warm-started from: `{what}` (its own card says what it learned from)")
    lines.append("")
    for section in ("normalisation", "sampling", "training_data", "metrics", "transfer"):
        if section not in card:
            continue
        lines += [f"## {section.replace('_', ' ').capitalize()}", "", "| key | value |", "|---|---|"]
        for k, v in card[section].items():
            lines.append(f"| {k} | {_fmt(v)} |")
        lines.append("")
    if "config" in card:
        lines += [
            "## Training configuration",
            "",
            "```json",
            json.dumps(card["config"], indent=2, sort_keys=True),
            "```",
            "",
        ]
    return "\n".join(lines)


def write_card(directory: str | os.PathLike[str], card: Mapping[str, Any]) -> None:
    """Write ``model_card.json`` and ``MODEL_CARD.md`` into ``directory``."""
    write_card_json(directory, card)
    (Path(directory) / "MODEL_CARD.md").write_text(card_markdown(card))


def write_card_json(directory: str | os.PathLike[str], card: Mapping[str, Any]) -> None:
    """Write ``model_card.json`` alone (the Markdown card does not list the files)."""
    (Path(directory) / CARD_FILE).write_text(json.dumps(card, indent=2, sort_keys=True, default=str) + "\n")
