"""The Snakemake workflow itself: lint, a small zone, a bad block, adding a block."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import uuid

import laspy
import numpy as np
import pytest
import yaml

from conftest import REPO, RGBNIR_BLOCK, write_zone_config
from towerpipe.io.columns import read_meta
from towerpipe.towers.shape import VERIFIER_RELEASE

pytestmark = [pytest.mark.usefixtures("pdal_cli"), pytest.mark.slow]


def snakemake(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "snakemake", *args], cwd=REPO, capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise AssertionError(f"snakemake {' '.join(args)} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


def test_lint_is_clean():
    proc = snakemake("--lint", check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Lints for" not in proc.stdout + proc.stderr


def split_in_blocks(src, out_dir, n=3):
    """Cut a real tile into n blocks along x (all attributes and VLRs kept)."""
    las = laspy.read(src)
    edges = np.linspace(las.header.mins[0], las.header.maxs[0] + 1e-6, n + 1)
    out_dir.mkdir(parents=True)
    for i in range(n):
        part = laspy.LasData(las.header)
        part.points = las.points[(las.x >= edges[i]) & (las.x < edges[i + 1])]
        part.write(out_dir / f"b{i}.laz")
    return sorted(out_dir.glob("*.laz"))


@pytest.fixture(scope="module")
def random_model(random_model_factory):
    """A randomly initialised model bundle: the plumbing tests do not depend on model quality."""
    return random_model_factory("full")


@pytest.fixture
def zone(tmp_path):
    name = f"pytest_{uuid.uuid4().hex[:8]}"
    yield name, tmp_path
    shutil.rmtree(REPO / "results" / name, ignore_errors=True)


def write_config(tmp_path, zone, indir, model, **extra):
    # gate 1.0: no window passes, the products are made with no towers (plumbing only)
    cfg = {
        "zones": {zone: {"input": str(indir)}},
        "workdir": str(tmp_path / "work"),
        "preprocess": {"tile_size": 200.0},
        "inference": {"model": str(model), "gate": 1.0},
    }
    cfg.update(extra)
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def planned_jobs(proc):
    """Jobs a dry run plans: its job table's total, or 0 where Snakemake says so."""
    m = re.search(r"^total\s+(\d+)", proc.stdout, re.M)
    if m:
        return int(m.group(1))
    assert "Nothing to be done" in proc.stdout + proc.stderr, (proc.stdout + proc.stderr)[-3000:]
    return 0


def planned(proc):
    """(rule, block) of every job of a dry run."""
    jobs = re.findall(r"^rule (\w+):\n(.*?)(?=^rule |\Z)", proc.stdout, re.M | re.S)
    return [(r, (re.search(r"block=([^,\s]+)", body) or [None, None])[1]) for r, body in jobs]


def executed(proc):
    """(rule, block) of every job a real run executed."""
    text = proc.stdout + proc.stderr
    jobs = re.findall(r"^(?:local)?rule (\w+):\n(.*?)(?=^\[|\Z)", text, re.M | re.S)
    return [(r, (re.search(r"block=([^,\s]+)", body) or [None, None])[1]) for r, body in jobs]


def job_count(proc, rule):
    m = re.search(rf"^{rule}\s+(\d+)$", proc.stdout, re.M)
    return int(m.group(1)) if m else 0


@pytest.mark.shared
def test_zone_runs_and_adding_a_block_reruns_only_it(zone, random_model):
    name, tmp = zone
    blocks = split_in_blocks(RGBNIR_BLOCK, tmp / "all")
    indir = tmp / "in"
    indir.mkdir()
    for b in blocks[:2]:
        shutil.copy(b, indir / b.name)
    cfg = write_config(tmp, name, indir, random_model)
    snakemake("--cores", "2", f"results/{name}/", f"--configfile={cfg}")
    out = REPO / "results" / name
    assert sorted(p.name for p in (out / "blocks").iterdir()) == ["b0.laz", "b1.laz"]
    assert sorted(p.name for p in (out / "towers").iterdir()) == ["b0.gpkg", "b1.gpkg"]
    assert {"b0.html", "b1.html", "index.html"} <= {p.name for p in (out / "qa").iterdir()}
    assert (out / "towers.gpkg").is_file()
    # `snakemake --report` holds the zone's QA index and its GeoPackage
    report = tmp / "report.html"
    snakemake("--report", str(report), f"results/{name}/", f"--configfile={cfg}")
    html = report.read_text()
    assert f"results/{name}/qa/index.html" in html and f"results/{name}/towers.gpkg" in html
    # nothing changed: nothing to do
    assert planned_jobs(snakemake("-n", "--cores", "2", f"results/{name}/", f"--configfile={cfg}")) == 0
    # a new block: its split, its tiles, its summary, the neighbours' edge tiles and the assembly.
    # The tiles are planned from the split's measured bounds (a checkpoint), so a dry run
    # cannot list them before the split: count the jobs the run executes
    shutil.copy(blocks[2], indir / blocks[2].name)
    proc = snakemake("--cores", "2", f"results/{name}/", f"--configfile={cfg}")
    jobs = executed(proc)
    assert [j for j in jobs if j[0] == "split_block"] == [("split_block", "b2")], jobs
    # the new block, plus the neighbour whose edge tile now has the new block in its buffer
    # (its windows see across the seam); a block not touching the new one is not
    # preprocessed nor inferred again. It is re-merged: its classes follow the towers its
    # neighbour reports (a tower across their edge belongs to one of them), and those were
    # recomputed
    assert len([j for j in jobs if j[0] == "merge_block"]) == 3, jobs
    heavy = {"split_block", "preprocess_tile", "infer_tile"}
    assert not [j for j in jobs if j[1] == "b0" and j[0] in heavy], jobs
    assert len([j for j in jobs if j[0] == "assemble_zone"]) == 1
    assert planned_jobs(snakemake("-n", "--cores", "2", f"results/{name}/", f"--configfile={cfg}")) == 0
    # a run that stopped between a split and the plan leaves the last publication without
    # its plan: the zone is planned and published again (from its products, all up to date),
    # never "done" with no results/<zone>/
    (tmp / "work" / name / "plan.json").unlink()
    shutil.rmtree(out)
    assert "plans and publishes the zone again" in snakemake("-n", f"results/{name}/", f"--configfile={cfg}").stdout
    proc = snakemake("--cores", "2", f"results/{name}/", f"--configfile={cfg}")
    # (the plan is a checkpoint: the log names it apart from the rules)
    assert sorted(r for r, _ in executed(proc)) == ["assemble_zone", "zone_results"], executed(proc)
    assert (tmp / "work" / name / "plan.json").is_file()
    assert sorted(p.name for p in (out / "blocks").iterdir()) == ["b0.laz", "b1.laz", "b2.laz"]
    # a changed model reprocesses every tile of every block, with the model the zone chose
    (random_model / "segmenter.pt").touch()
    proc = snakemake("-n", "--cores", "2", f"results/{name}/", f"--configfile={cfg}")
    n_tiles = len(list((tmp / "work" / name / "tiles").rglob("*.npz")))
    assert job_count(proc, "infer_tile") >= n_tiles, proc.stdout[-3000:]
    assert job_count(proc, "merge_block") == 3
    assert job_count(proc, "choose_model") == 0
    # a card stamped anew (its real-shape scores decide `auto`) makes the zone's choice again (a
    # touch alone is not a change: Snakemake compares the checksums of small inputs)
    card_file = random_model / "model_card.json"
    card = json.loads(card_file.read_text())
    card_file.write_text(json.dumps({**card, "transfer": {"score": 0.5, "resolution": 0.014}}))
    try:
        proc = snakemake("-n", "--cores", "2", f"results/{name}/", f"--configfile={cfg}")
        assert job_count(proc, "choose_model") == 1, proc.stdout[-3000:]
    finally:
        card_file.write_text(json.dumps(card))  # the module's other tests share the model


@pytest.mark.shared
def test_another_model_reruns_every_tile(zone, random_model, random_model_factory):
    """A zone given another model (``inference.model``) runs its tiles again with it, and its
    products after them: the choice is a checkpoint, the tile jobs are judged once it is made."""
    name, tmp = zone
    indir = tmp / "in"
    split_in_blocks(RGBNIR_BLOCK, indir, n=2)
    snakemake("--cores", "2", f"results/{name}/", f"--configfile={write_config(tmp, name, indir, random_model)}")
    n_tiles = len(list((tmp / "work" / name / "tiles").rglob("*.npz")))
    other = random_model_factory("shape")
    proc = snakemake("--cores", "2", f"results/{name}/", f"--configfile={write_config(tmp, name, indir, other)}")
    jobs = [r for r, _ in executed(proc)]
    assert jobs.count("infer_tile") == n_tiles and jobs.count("merge_block") == 2, jobs
    preds = sorted((tmp / "work" / name / "pred").rglob("*.npz"))
    assert {read_meta(p)["model"]["name"] for p in preds} == {"towerpipe-random-shape"}


@pytest.mark.shared
def test_bad_block_costs_only_itself(zone, random_model):
    name, tmp = zone
    indir = tmp / "in"
    blocks = split_in_blocks(RGBNIR_BLOCK, indir, n=2)
    (indir / "broken.laz").write_bytes(b"not a point cloud" * 100)
    cfg = write_config(tmp, name, indir, random_model)
    proc = snakemake("--cores", "2", "--keep-going", f"results/{name}/", f"--configfile={cfg}", check=False)
    assert proc.returncode != 0
    # the end-of-run line counts the failed block and says where the QA index is
    assert re.search(
        rf"towerpipe: zone {name}: 0 towers in 3 blocks, 1 failed.*QA index: results/{name}/qa/index.html",
        proc.stdout + proc.stderr,
    ), proc.stdout[-2000:] + proc.stderr[-2000:]
    work = tmp / "work" / name
    assert sorted(p.name for p in (work / "out").iterdir()) == sorted(f"{b.stem}.laz" for b in blocks)
    # the split records the error (neighbours go on without the block), the block's own
    # next step fails with it
    assert sorted(p.name for p in (work / "cache" / "broken").iterdir() if not p.name.startswith(".")) == ["meta.json"]
    log = (work / "logs" / "towers_block" / "broken.log").read_text()
    assert re.search(r"InputError: .*broken\.laz: not a readable LAS/LAZ file", log), log
    # the zone directory is published as INCOMPLETE, its QA index naming the bad block and why
    out = REPO / "results" / name
    assert "broken: towers_block: InputError" in (out / "INCOMPLETE.txt").read_text()
    index = (out / "qa" / "index.html").read_text()
    assert "broken" in index and "not a readable LAS/LAZ file" in index
    assert sorted(p.name for p in (out / "blocks").iterdir()) == sorted(f"{b.stem}.laz" for b in blocks)


def test_a_new_training_zone_reruns_the_training(ci_scene, tmp_path):
    """Snakemake does not rerun a job whose output exists for a checkpoint it waits on (a new
    zone's plan): the training manifest's new parameters do rerun the windows and verifiers."""
    work = tmp_path / "work"
    uid = uuid.uuid4().hex[:6]
    zones = {f"pytest_train_{k}_{uid}": {"input": str(ci_scene)} for k in "ab"}
    a, b = zones
    cfg = write_zone_config(tmp_path / "c.yaml", zones, work, training={"zones": [a]})
    manifest, windows = work / "models" / "training_zones.json", work / "models" / "windows.npz"
    snakemake("--cores", "1", str(manifest), f"--configfile={cfg}")
    assert yaml.safe_load(manifest.read_text())["zones"] == [a]
    windows.touch()  # the windows of zone a
    assert "training_manifest" not in {r for r, _ in planned(snakemake("-n", str(windows), f"--configfile={cfg}"))}

    write_zone_config(cfg, zones, work, training={"zones": [a, b]})
    proc = snakemake("-n", str(windows), f"--configfile={cfg}")
    assert {"training_manifest", "training_windows"} <= {r for r, _ in planned(proc)}, proc.stdout[-2000:]


def test_a_dry_run_of_the_training_plans_a_zone_not_generated_yet(tmp_path):
    """``make train -n`` on a fresh clone: the training zones are synthetic and not generated
    yet, so the training waits on their generation (the plan asks for the zone's input first), and
    a plan asked for before it waits on that checkpoint; the plan's resources must not (Snakemake
    9.27 failed the dry run with "'int' object has no attribute 'constrain'")."""
    zone = f"pytest_drysynth_{uuid.uuid4().hex[:6]}"
    zones = {zone: {"input": f"data/{zone}", "synth": {"seed": 5, "blocks": 1, "size": 200}}}
    work = tmp_path / "work"
    cfg = write_zone_config(tmp_path / "c.yaml", zones, work, training={"zones": [zone]})
    proc = snakemake("-n", str(work / "models" / "windows.npz"), f"--configfile={cfg}")
    synth_job = re.compile(r"^checkpoint synth_zone:\n(?:.*\n)*?\s+wildcards: zone=" + zone, re.M)
    assert synth_job.search(proc.stdout), proc.stdout[-2000:]
    assert "training_manifest" in {r for r, _ in planned(proc)}
    proc = snakemake("-n", str(work / zone / "plan.json"), f"--configfile={cfg}")
    plan_job = re.compile(r"^checkpoint plan_zone:\n(?:.*\n)*?\s+wildcards: zone=" + zone, re.M)
    assert plan_job.search(proc.stdout), proc.stdout[-2000:]
    assert not (REPO / "data" / zone).exists()


def test_a_split_cut_short_is_finished_before_the_plan(tmp_path):
    """A synthetic verifier zone whose split was cut short (a block's cache missing, no plan yet),
    asked for through the verifier's input (the tiles of every zone it trains on): the missing
    split comes before the plan. Snakemake 9.27 ran the plan first, its input unresolved while it
    waited on the zone's input checkpoint, and the plan failed (a dry run planned no split)."""
    uid = uuid.uuid4().hex[:6]
    zones = {
        f"pytest_cut_{k}_{uid}": {"input": f"data/pytest_cut_{k}_{uid}", "synth": {"seed": 5, "blocks": 2, "size": 150}}
        for k in "ab"
    }
    a, b = zones
    work = tmp_path / "work"
    cfg = write_zone_config(tmp_path / "c.yaml", zones, work, training={"zones": [a], "verifier_zones": [b]})
    try:
        snakemake("--cores", "1", *(str(work / z / "prepared.done") for z in zones), f"--configfile={cfg}")
        caches = sorted((work / b / "cache").iterdir())
        assert len(caches) == 2
        # as a run killed in the split leaves it: one block split, the other not, no plan
        shutil.rmtree(caches[0])
        for p in (work / b / "tiles", work / b / "dtm"):
            shutil.rmtree(p)
        for p in (work / b / "plan.json", work / b / "prepared.done"):
            p.unlink()
        proc = snakemake(
            "-n", str(work / "verifiers" / f"towerpipe-verifier-v{VERIFIER_RELEASE}"), f"--configfile={cfg}"
        )
        assert ("split_block", caches[0].name) in planned(proc), proc.stdout[-2000:]
    finally:
        for z in zones:
            shutil.rmtree(REPO / "data" / z, ignore_errors=True)


def test_a_verifier_zone_retrains_the_verifier(ci_scene, tmp_path):
    """``training.verifier_zones``: the verifier's own manifest lists them, so a zone added
    there reruns the verifier and leaves the networks' manifest as it is."""
    work = tmp_path / "work"
    uid = uuid.uuid4().hex[:6]
    zones = {f"pytest_verify_{k}_{uid}": {"input": str(ci_scene)} for k in "ab"}
    a, b = zones
    cfg = write_zone_config(tmp_path / "c.yaml", zones, work, training={"zones": [a], "verifier_zones": []})
    models = work / "models"
    snakemake(
        "--cores", "1", str(models / "training_zones.json"), str(models / "verifier_zones.json"), f"--configfile={cfg}"
    )
    assert yaml.safe_load((models / "verifier_zones.json").read_text())["zones"] == [a]
    verifier = work / "verifiers" / f"towerpipe-verifier-v{VERIFIER_RELEASE}"
    (models / "windows.npz").touch()
    verifier.mkdir(parents=True)
    (verifier / "verifier.json").touch()

    targets = (str(models / "windows.npz"), str(verifier), f"--configfile={cfg}")
    assert not {"training_manifest", "train_verifier"} & {r for r, _ in planned(snakemake("-n", *targets))}

    write_zone_config(cfg, zones, work, training={"zones": [a], "verifier_zones": [b, a]})
    proc = snakemake("-n", *targets)
    assert "train_verifier" in {r for r, _ in planned(proc)}, proc.stdout[-2000:]
    # the networks' manifest stays (the windows here wait on zone a's plan, never made)
    manifests = re.findall(r"^rule training_manifest:\n\s+output: (\S+)", proc.stdout, re.M)
    assert [m.rsplit("/", 1)[-1] for m in manifests] == ["verifier_zones.json"]
