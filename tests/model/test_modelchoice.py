"""Which model a zone runs with: `auto` by valid attributes and transfer, explicit choices, errors."""

from __future__ import annotations

import json

import pytest

from conftest import grid_inference
from towerpipe.errors import ConfigError, ModelError
from towerpipe.inference.infer import infer_tile
from towerpipe.model import cards as modelcard
from towerpipe.model.choice import choose_model, incompatibility_error, resolve_model, zone_attributes
from towerpipe.model.features import FEATURE_SETS

RELEASES = {"full": 9, "rgb": 9, "geometry": 9, "shape": 9}


def _attrs(*valid):
    return {
        a: {"present": True, "valid": a in valid, "reason": "ok" if a in valid else "all 0"}
        for a in ("intensity", "returns", "rgb", "nir")
    }


@pytest.fixture
def shipped(tmp_path, monkeypatch):
    """A models directory with a card per feature set; ``scores`` sets their transfer scores."""
    monkeypatch.setenv(modelcard.MODELS_ENV, str(tmp_path))
    for fs, r in RELEASES.items():
        monkeypatch.setitem(modelcard.MODEL_RELEASES, fs, r)
    for fs in list(modelcard.MODEL_RELEASES):
        if fs not in RELEASES:
            monkeypatch.delitem(modelcard.MODEL_RELEASES, fs)

    def scores(resolution=None, spread=None, **transfer):
        for fs, r in RELEASES.items():
            d = tmp_path / f"towerpipe-{fs}-v{r}"
            d.mkdir(exist_ok=True)
            card = {
                "name": f"towerpipe-{fs}",
                "version": str(r),
                "bundle_version": modelcard.BUNDLE_VERSION,
                "feature_set": fs,
                "features": FEATURE_SETS[fs],
                "normalisation": {},
                "sampling": {"n_points": 1024},
                "training_data": {},
                "metrics": {},
                "code": {},
                "config_hash": "0",
                "transfer": {"score": transfer.get(fs), "resolution": resolution, "spread": spread},
            }
            (d / "model_card.json").write_text(json.dumps(card))
        return tmp_path

    return scores


def test_auto_picks_the_best_transfer_among_usable_models(shipped):
    shipped(full=0.70, rgb=0.95, geometry=0.80, shape=0.90)
    c = choose_model("auto", {"a": _attrs("intensity", "returns", "rgb", "nir")}, zone="z")
    assert c["feature_set"] == "rgb" and c["mode"] == "auto"
    assert "transfers best" in c["reason"] and "rgb 0.950" in c["reason"]
    # the corridor case: RGB, but intensity and returns all 0 and no NIR -> rgb or shape only
    c = choose_model("auto", {"a": _attrs("rgb"), "b": _attrs("rgb", "intensity")}, zone="z")
    assert c["feature_set"] == "rgb" and c["valid_attributes"] == ["rgb"]
    assert {x["feature_set"]: x["missing"] for x in c["candidates"]}["geometry"] == ["intensity", "returns"]
    # one block without colour: the whole zone runs with what every block has
    c = choose_model(
        "auto", {"a": _attrs("rgb", "intensity", "returns"), "b": _attrs("intensity", "returns")}, zone="z"
    )
    assert c["feature_set"] == "shape"


def test_richer_is_not_better(shipped):
    shipped(full=0.5, rgb=0.6, geometry=0.55, shape=0.9)
    c = choose_model("auto", {"a": _attrs("intensity", "returns", "rgb", "nir")}, zone="z")
    assert c["feature_set"] == "shape"


def test_scores_within_one_benchmark_tower_tie_and_the_leaner_model_wins(shipped):
    every = {"a": _attrs("intensity", "returns", "rgb", "nir")}
    # geometry 0.009 above shape, one tower weighs 0.018: a tie, shape reads no sensor attribute
    shipped(resolution=0.018, geometry=0.890, shape=0.881, full=0.5, rgb=0.6)
    c = choose_model("auto", every, zone="z")
    assert c["feature_set"] == "shape"
    assert "tie" in c["reason"] and "0.018" in c["reason"] and "geometry 0.890" in c["reason"]
    # more than one tower apart: the better score wins, however many columns it reads
    shipped(resolution=0.018, geometry=0.920, shape=0.881, full=0.5, rgb=0.6)
    c = choose_model("auto", every, zone="z")
    assert c["feature_set"] == "geometry" and "transfers best" in c["reason"] and "tie" not in c["reason"]
    # a card stamped without a resolution: strict order, as before the rule
    shipped(geometry=0.890, shape=0.881, full=0.5, rgb=0.6)
    assert choose_model("auto", every, zone="z")["feature_set"] == "geometry"
    # scores apart by more than a tower, but within the spread between trainings of a recipe: a tie
    shipped(resolution=0.014, geometry=0.882, shape=0.840, full=0.5, rgb=0.6)
    assert choose_model("auto", every, zone="z")["feature_set"] == "geometry"
    shipped(resolution=0.014, spread=0.051, geometry=0.882, shape=0.840, full=0.5, rgb=0.6)
    c = choose_model("auto", every, zone="z")
    assert c["feature_set"] == "shape" and "0.051" in c["reason"]
    # the tie is among usable models only: without intensity, geometry is not a candidate
    shipped(resolution=0.5, geometry=0.95, shape=0.2, rgb=0.6, full=0.1)
    assert choose_model("auto", {"a": _attrs("rgb", "nir")}, zone="z")["feature_set"] == "shape"


def test_failed_blocks_do_not_decide(shipped):
    shipped(full=0.99, rgb=0.9, geometry=0.8, shape=0.7)
    assert zone_attributes({"a": _attrs("intensity", "returns", "rgb", "nir"), "bad": None}) == {
        "intensity",
        "returns",
        "rgb",
        "nir",
    }
    assert (
        choose_model("auto", {"a": _attrs("intensity", "returns", "rgb", "nir"), "bad": None}, zone="z")["feature_set"]
        == "full"
    )


def test_unmeasured_models_rank_last(shipped):
    shipped(shape=0.4)
    c = choose_model("auto", {"a": _attrs("intensity", "returns", "rgb", "nir")}, zone="z")
    assert c["feature_set"] == "shape" and "(not measured)" in c["reason"]


def test_explicit_choice_lists_incompatible_blocks_with_the_real_key(shipped):
    shipped(full=0.9, shape=0.8)
    c = choose_model(
        "full",
        {"a": _attrs("intensity", "returns", "rgb", "nir"), "b": _attrs("rgb")},
        zone="zone2",
        key="zones.zone2.model",
    )
    assert c["mode"] == "explicit" and c["incompatible_blocks"] == {"b": ["intensity", "nir"]}
    msg = incompatibility_error(c, "b")
    assert "`zones.zone2.model: auto`" in msg and "intensity, nir" in msg
    assert incompatibility_error(c, "a") is None


def test_bad_specs_name_the_fix(shipped, tmp_path):
    shipped()
    with pytest.raises(ConfigError, match="inference.model: .*nowhere.*is not a towerpipe model"):
        choose_model(str(tmp_path / "nowhere"), {}, zone="z")
    with pytest.raises(ConfigError, match="chosen per zone"):
        resolve_model("auto")
    assert resolve_model("shape").name == "towerpipe-shape-v9"


def test_an_explicit_incompatible_model_fails_its_block_only(random_model_factory, tmp_path):
    """The prediction of a block the chosen model cannot use fails with the config key to change."""
    from towerpipe.io.tiles import Tile, empty_arrays, save_tile

    a = empty_arrays(3)
    a["model_input"][:] = True
    a["core"][:] = True
    tile = tmp_path / "t.npz"
    save_tile(
        tile,
        Tile(
            a,
            {
                "zone": "z",
                "block": "b",
                "tile": "0_0",
                "blocks": ["b"],
                "crs_wkt": None,
                "core_bounds": [0, 0, 1, 1],
                "valid_attributes": ["rgb"],
                "color_bits": 16,
            },
        ),
    )
    choice = {
        "mode": "explicit",
        "key": "inference.model",
        "name": "towerpipe-random-full",
        "version": "0",
        "feature_set": "full",
        "reason": "set by `inference.model: full`",
        "incompatible_blocks": {"b": ["intensity", "nir"]},
    }
    with pytest.raises(ModelError, match="set `inference.model: auto`"):
        infer_tile(tile, random_model_factory("full"), tmp_path / "p.npz", grid_inference(), choice=choice)
