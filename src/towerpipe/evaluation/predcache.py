"""A labelled zone's predictions for an inference setting, made once and cached.

The calibration (:mod:`towerpipe.evaluation.calibrate`) and the real-shape benchmark
(:mod:`towerpipe.evaluation.realshape`) score many settings of the tower rules on the same
predictions. :func:`zone_predictions` predicts each tile of a zone's last run once per inference
setting, model, shape gate and version of the code that makes predictions, under
``<workdir>/<zone>/calibrate/<model>_tta<views>_<key>/``: a change to any of them never reuses
old predictions, and a change to anything else (the tower rules) never predicts again.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from towerpipe.config import InferenceConfig
from towerpipe.errors import InputError
from towerpipe.io import workdir

__all__ = ["INFERENCE_PACKAGES", "NOT_INFERENCE", "inference_code", "zone_predictions", "zone_tiles"]

#: The subpackages and modules whose code makes a tile's predictions: all of their modules
#: are part of the key of the cached predictions (:func:`zone_predictions`). Of the tower
#: code the wire detector (the peaks leave overhead wires out), the shape module (the
#: shape gate cuts and scores the object at each peak), the plan hull it cuts objects with and the
#: k-d trees they query: the tower rules run after the predictions and never invalidate them.
INFERENCE_PACKAGES = (
    "towerpipe.inference",
    "towerpipe.model",
    "towerpipe.towers.wires",
    "towerpipe.towers.shape",
    "towerpipe.towers.hull",
    "towerpipe.towers.kdtree",
)
#: Modules of those packages that make no prediction: a zone's model choice (the calibration
#: names the model, whose weights' checksums are in the key). A new module is part of the key
#: until listed here.
NOT_INFERENCE = ("towerpipe.model.choice",)


def zone_tiles(work: str | os.PathLike[str], zone: str) -> list[Path]:
    """The tiles of the zone's last run (:func:`towerpipe.io.workdir.zone_files`), or the command to make them."""
    if tiles := workdir.zone_files(work, zone, workdir.TILE):
        return tiles
    raise InputError(Path(work, zone), f"no tiles of zone {zone!r}; run `snakemake --cores 2 results/{zone}/` first")


def zone_predictions(
    work: str | os.PathLike[str],
    zone: str,
    model: str | os.PathLike[str],
    settings: InferenceConfig,
    verifier: str | os.PathLike[str] = "none",
) -> list[str]:
    """Prediction files of every tile of a zone with ``settings.tta`` views, computed once and cached.

    Parameters
    ----------
    work
        The workdir (``work``); tiles are read from the zone's last run (:func:`towerpipe.io.workdir.zone_files`).
    zone
        Zone name.
    model
        Model bundle directory.
    settings
        The inference settings (the config's ``inference`` section, with the candidate's
        views and gate).
    verifier
        The shape gate's verifier (``towers.verifier``; see :func:`towerpipe.inference.infer.infer_tile`).

    Returns
    -------
    list of str
        ``<work>/<zone>/calibrate/<model>_tta<k>_<hash>/<block>_<tile>.npz``, one per tile;
        the hash covers the inference settings, the model's weights and the shape gate's verifier.
    """
    from towerpipe.inference.infer import infer_tile
    from towerpipe.model.bundle import load_bundle
    from towerpipe.model.cards import config_hash, read_card, sha256
    from towerpipe.towers.shape import VERIFIER_FILE, resolve_verifier

    tiles = zone_tiles(work, zone)
    # every inference setting (the views name the directory): a new one can never reuse old predictions
    kw = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings) if f.name != "tta"}
    gate_by = resolve_verifier(str(verifier)) if settings.shape_gate > 0 else None
    # the weights' hashes (the shape gate's too) and the inference code are part of the key: a
    # retrained model or another way of placing windows never reuses old predictions
    key = config_hash(
        {
            "inference": kw,
            "weights": read_card(model).get("files"),
            "verifier": sha256(gate_by / VERIFIER_FILE) if gate_by else None,
            "code": inference_code(),
        }
    )
    out_dir = Path(work, zone, "calibrate", f"{Path(model).name}_tta{settings.tta}_{key}")
    bundle = None
    paths = []
    for t in tiles:
        out = out_dir / f"{t.parent.name}_{t.stem}.npz"
        if not out.exists() or out.stat().st_mtime < t.stat().st_mtime:
            bundle = bundle or load_bundle(model)
            infer_tile(t, bundle, out, settings, verifier=str(verifier))
        paths.append(str(out))
    return paths


def inference_code() -> str:
    """SHA-256 of the code that turns a tile into predictions.

    Every module of :data:`INFERENCE_PACKAGES` but those of :data:`NOT_INFERENCE` (path and
    content, in sorted order): the windows, the networks, their features and sampling, the wire
    detector (the peaks leave overhead wires out) and the shape gate's cut and score of a peak's
    object, wherever in those subpackages it lives.
    """
    import hashlib
    from importlib.util import find_spec

    h = hashlib.sha256()
    package = Path(find_spec("towerpipe").origin).parent
    skip = {Path(find_spec(name).origin) for name in NOT_INFERENCE}
    for name in INFERENCE_PACKAGES:
        spec = find_spec(name)
        origin = Path(spec.origin)
        for path in sorted(origin.parent.rglob("*.py")) if spec.submodule_search_locations else [origin]:
            if path in skip:
                continue
            h.update(path.relative_to(package).as_posix().encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]
