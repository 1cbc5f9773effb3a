"""towerpipe.jobs.zone: a publication whose plan is missing is set aside, so the run rebuilds it."""

from towerpipe.jobs.zone import set_aside_unplanned
from towerpipe.products import layout


def _zone(tmp_path, *, plan=False, manifest=False, results=None):
    paths = {k: tmp_path / k for k in ("plan.json", "published.json", "results", "aside")}
    if plan:
        paths["plan.json"].write_text("{}")
    if manifest:
        paths["published.json"].write_text("{}")
    if results is not None:
        paths["results"].mkdir()
        (paths["results"] / "towers.gpkg").write_text("towers")
        if results == "incomplete":
            (paths["results"] / layout.INCOMPLETE).write_text("b1: failed")
    return paths


def _call(p, **kw):
    return set_aside_unplanned(p["plan.json"], p["published.json"], p["results"], p["aside"], **kw)


def test_with_its_plan_nothing_is_touched(tmp_path):
    p = _zone(tmp_path, plan=True, manifest=True, results="incomplete")
    assert _call(p) is None
    assert p["published.json"].exists() and (p["results"] / layout.INCOMPLETE).exists()


def test_nothing_published_nothing_to_do(tmp_path):
    assert _call(_zone(tmp_path)) is None


def test_a_manifest_without_plan_is_removed_complete_results_stay(tmp_path):
    p = _zone(tmp_path, manifest=True, results="complete")
    msg = _call(p)
    assert "plan.json is missing" in msg and "moved" not in msg
    assert not p["published.json"].exists()
    assert (p["results"] / "towers.gpkg").read_text() == "towers"
    assert not p["aside"].exists()


def test_incomplete_results_without_plan_are_moved_aside(tmp_path):
    p = _zone(tmp_path, results="incomplete")
    p["aside"].mkdir()
    (p["aside"] / "old").write_text("an older incomplete zone")
    msg = _call(p)
    assert f"moved to {p['aside']}" in msg
    assert not p["results"].exists()
    assert (p["aside"] / layout.INCOMPLETE).exists() and not (p["aside"] / "old").exists()


def test_a_dry_run_says_so_and_touches_nothing(tmp_path):
    p = _zone(tmp_path, manifest=True, results="incomplete")
    assert "a run plans and publishes the zone again" in _call(p, dry_run=True)
    assert p["published.json"].exists() and (p["results"] / layout.INCOMPLETE).exists()
