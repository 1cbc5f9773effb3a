"""Training's bookkeeping: the manifest of the training zones, and publishing a trained model
(``results/models/<name>/`` from its bundle and ablation tables)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from towerpipe.io.atomic import assemble_directory, write_text_atomic


def training_manifest_step(zones: Sequence[str], dataset: dict, out: str) -> Path:
    """Write the training zones and window settings to ``out`` (JSON).

    The training windows and the verifiers read the manifest as an input. Snakemake does not
    rerun a job whose output exists because a checkpoint it waits on (a new training zone's
    generation or plan) is missing; a new manifest (its parameters changed) does rerun them.
    """
    return write_text_atomic(out, json.dumps({"zones": list(zones), "dataset": dataset}, indent=1, sort_keys=True))


def model_results_step(bundle_dir: str, ablation_dirs: Sequence[str], out_dir: str) -> Path:
    """``results/models/<name>/``: checkpoint, card, curves, ``metrics.json`` (+ ablation), atomically."""
    files = {p.name: str(p) for p in sorted(Path(bundle_dir).iterdir()) if p.is_file()}
    for d in ablation_dirs:
        files.update({p.name: str(p) for p in sorted(Path(d).iterdir()) if p.is_file()})

    def build(tmp: Path) -> None:
        from towerpipe.model.cards import CARD_FILE

        card = json.loads((Path(bundle_dir) / CARD_FILE).read_text())
        (tmp / "metrics.json").write_text(json.dumps(card.get("metrics", {}), indent=1))

    return assemble_directory(out_dir, files, build)
