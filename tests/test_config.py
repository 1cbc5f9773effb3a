"""The configuration: schema defaults, one line per problem, the strict top level, `towerpipe run`."""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

from conftest import REPO
from towerpipe.cli import main
from towerpipe.config import CONFIG_FILE, SCHEMA_FILE, load_config, load_yaml, validate_config
from towerpipe.errors import ConfigError

SCHEMA = load_yaml(REPO / SCHEMA_FILE, "schema")


def problems(cfg):
    with pytest.raises(ConfigError) as exc:
        validate_config(cfg, SCHEMA)
    return str(exc.value).splitlines()


def test_shipped_config_is_valid_and_defaults_come_from_the_schema():
    cfg = load_config(root=REPO)
    assert cfg["workdir"] == "work"
    small = validate_config({"zones": {"z": {"input": "in"}}}, SCHEMA)
    assert small["preprocess"]["tile_size"] == SCHEMA["properties"]["preprocess"]["properties"]["tile_size"]["default"]
    assert small["towers"]["min_points"] == 20 and small["towers"]["min_split_points"] == 20


def test_unknown_keys_name_the_closest_valid_one():
    assert problems({"zones": {"z": {"input": "in"}}, "infrence": {}}) == [
        "config: infrence: unknown key; did you mean 'inference'?"
    ]
    assert problems({"zones": {"z": {"input": "in", "crs": None}}, "inference": {"treshold": 0.4}}) == [
        "config: inference.treshold: unknown key; did you mean 'threshold'?"
    ]
    assert problems({"zones": {"z": {"input": "in"}}, "colour": 1}) == [
        "config: colour: unknown key; valid keys: zones, workdir, preprocess, batch, inference, towers, qa, training"
    ]
    assert problems({"zones": {"z": {"input": "in"}}, "qa": {"min_densty": 1.0}}) == [
        "config: qa.min_densty: unknown key; did you mean 'min_density'?"
    ]


def test_a_zone_crs_is_read_before_any_job():
    """A CRS pyproj cannot read stops the run at validation, naming the key and a form it reads."""
    assert validate_config({"zones": {"z": {"input": "in", "crs": "EPSG:25831"}}}, SCHEMA)
    for bad in ("EPSG:99999", "EPSG25831"):
        (line,) = problems({"zones": {"z": {"input": "in", "crs": bad}}})
        assert line.startswith(f"config: zones.z.crs: '{bad}' is not a CRS (") and 'e.g. "EPSG:25831"' in line


def test_one_line_per_problem():
    lines = problems(
        {"zones": {"z": {"inptu": "in"}}, "inference": {"gate": 1.5, "tta": 3}, "preprocess": {"buffer": "wide"}}
    )
    assert lines == [
        "config: inference.gate: 1.5 is greater than the maximum of 1",
        "config: inference.tta: 3 is not one of [1, 2, 4, 8]",
        "config: preprocess.buffer: 'wide' is not of type 'number'",
        "config: zones.z: 'input' is a required property",
        "config: zones.z.inptu: unknown key; did you mean 'input'?",
    ]


def test_yaml_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("zones:\n  z: {input: [\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: not valid YAML \(line \d+, column \d+\)") as exc:
        load_yaml(bad)
    assert "\n" not in str(exc.value)
    with pytest.raises(ConfigError, match="no such file"):
        load_yaml(tmp_path / "none.yaml")


def snakemake_dry_run(*args):
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", *args], cwd=REPO, capture_output=True, text=True)
    # Snakemake's own notes (the profile it uses, config files merged) are not the error
    ours = [
        ln
        for ln in (proc.stdout + proc.stderr).splitlines()
        if ln.strip() and not ln.startswith(("Using workflow specific profile", "Config file "))
    ]
    return proc.returncode, ours


@pytest.mark.usefixtures("pdal_cli")
def test_snakemake_rejects_a_misspelled_section_in_one_line(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"infrence": {}}))
    rc, lines = snakemake_dry_run("results/demo/", f"--configfile={cfg}")
    assert rc == 1 and lines == ["config: infrence: unknown key; did you mean 'inference'?"]


@pytest.mark.usefixtures("pdal_cli")
def test_snakemake_unknown_zone_is_one_line():
    rc, lines = snakemake_dry_run("results/no_such_zone/")
    errors = [ln for ln in lines if "no_such_zone" in ln and "Command:" not in ln]
    assert rc == 1 and len(errors) == 1 and errors[0].startswith("config: zone 'no_such_zone' is not configured")
    assert not any("Traceback" in ln for ln in lines)


# --------------------------------------------------------------------------- towerpipe run
def test_run_config_errors_are_one_line(tmp_path, capsys):
    assert main(["run", "demo", "--config", str(tmp_path / "missing.yaml")]) == 1
    assert capsys.readouterr().err.strip() == (
        f"towerpipe: error: ConfigError: --config {tmp_path / 'missing.yaml'}: no such file"
    )
    (tmp_path / "c.yaml").write_text("infrence: {}\n")
    assert main(["run", "demo", "--config", str(tmp_path / "c.yaml")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "infrence: unknown key; did you mean 'inference'?" in err
    assert main(["run", "no_such_zone"]) == 1
    assert "zone 'no_such_zone' is not configured" in capsys.readouterr().err
    # an input directory without a block: one line before Snakemake starts (no banner)
    (tmp_path / "empty").mkdir()
    (tmp_path / "e.yaml").write_text(f"zones: {{ez: {{input: {tmp_path / 'empty'}}}}}\n")
    assert main(["run", "ez", "--config", str(tmp_path / "e.yaml")]) == 1
    out = capsys.readouterr()
    assert out.err.strip() == (
        f"towerpipe: error: ConfigError: zones.ez.input: no .las/.laz files under '{tmp_path / 'empty'}'"
    )
    assert "Snakemake version" not in out.out + out.err


@pytest.mark.usefixtures("pdal_cli")
@pytest.mark.shared
def test_run_plans_a_zone_with_the_config_after_the_zone(tmp_path, random_model_factory):
    from conftest import RGBNIR_SMALL

    indir = tmp_path / "in"
    indir.mkdir()
    (indir / "b0.laz").symlink_to(RGBNIR_SMALL)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "zones": {"runz": {"input": str(indir)}},
                "workdir": str(tmp_path / "work"),
                "inference": {"model": str(random_model_factory("full"))},
            }
        )
    )
    # the ordering trap of `snakemake --configfile F TARGET` cannot happen: the zone is positional
    proc = subprocess.run(
        [sys.executable, "-m", "towerpipe.cli", "run", "runz", "--config", str(cfg), "--cores", "1", "--dry-run"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "split_block" in out and "assemble_zone" in out
    assert not (REPO / "results" / "runz").exists()


def test_profile_keys_are_all_applied():
    from towerpipe.jobs.run import profile_settings

    prof = profile_settings(REPO)
    assert prof["dag"]["force_incomplete"] is True and prof["output"]["show_failed_logs"] is True
    assert prof["resources"]["cores"] == 2
    assert {t.item_to_choice() for t in prof["dag"]["rerun_triggers"]} == {"mtime", "params", "input", "code"}
    assert (REPO / CONFIG_FILE).is_file()


def test_defaults_live_only_in_the_schema_and_towerpipe_config_prints_them(tmp_path, capsys):
    shipped = load_yaml(REPO / CONFIG_FILE)
    assert set(shipped) == {"zones", "workdir"}  # every other setting: the schema's default
    mine = tmp_path / "mine.yaml"
    mine.write_text("inference: {gate: 0.2}\n")
    assert main(["config", str(mine)]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    # the shipped, calibrated values, and the file given merged over them
    assert cfg["inference"]["gate"] == 0.2 and cfg["inference"]["tta"] == 2 and cfg["inference"]["threshold"] == 0.3
    assert cfg["towers"]["min_core_prob"] == 0.25 and cfg["towers"]["max_base_ratio"] == 0.7
    assert cfg["qa"]["min_density"] == 2.0 and cfg["qa"]["max_gate_ratio"] == 0.25  # the QA limits
    assert "demo" in cfg["zones"] and cfg["training"]["models"]  # config/models.yaml too, as the workflow loads it


@pytest.mark.usefixtures("pdal_cli")
def test_a_model_that_is_not_there_stops_the_run_before_any_job(tmp_path):
    """A misspelt model path: one line naming the key and the path, before a block is split (it
    let a published zone keep last night's products, and made a new zone fail at its model choice)."""
    from conftest import RGBNIR_SMALL

    indir = tmp_path / "in"
    indir.mkdir()
    (indir / "b0.laz").symlink_to(RGBNIR_SMALL)
    for key, model in (("zones.mz.model", "results/models/agency-shape-v2"), ("inference.model", str(tmp_path / "no"))):
        zone = {"input": str(indir)}
        cfg = {"zones": {"mz": zone}, "workdir": str(tmp_path / "work")}
        if key.startswith("zones"):
            zone["model"] = model
        else:
            cfg["inference"] = {"model": model}
        (tmp_path / "m.yaml").write_text(yaml.safe_dump(cfg))
        rc, lines = snakemake_dry_run("results/mz/", f"--configfile={tmp_path / 'm.yaml'}")
        errors = [ln for ln in lines if ln.startswith("config:")]
        assert rc == 1 and errors == [
            f"config: {key}: no model at '{model}'; name `auto`, a shipped feature set "
            "(geometry, shape), the directory of a trained model, or results/models/<name> "
            "of a model in training.models"
        ], lines


def test_a_snakemake_error_is_told_by_its_message_not_its_label():
    from snakemake.exceptions import WorkflowError

    from towerpipe.jobs.run import error_line

    msg = "zone 'z' is one the models train on; give its input another zone name"
    assert error_line(WorkflowError(f"Error:\n  {msg}\n")) == msg  # it printed "failed: Error:"
    assert error_line(WorkflowError(msg)) == msg
    assert error_line(ValueError("")) == "ValueError"
