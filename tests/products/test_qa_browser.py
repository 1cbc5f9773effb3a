"""The QA pages in headless Chromium: no console errors, no horizontal overflow at 1,280 px."""

from __future__ import annotations

import numpy as np
import pytest
from test_qa import SIZE, X0, Y0, make_block, metas, report, towers_of

from towerpipe.products.qa.browser import PAGE_WIDTH, Browser, find_chromium
from towerpipe.products.qa.index import zone_index


@pytest.fixture(scope="module")
def browser():
    if find_chromium() is None:
        pytest.skip(
            "chromium is not installed (make setup runs scripts/install_chromium.sh; or set TOWERPIPE_CHROMIUM)"
        )
    with Browser() as b:
        yield b


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    """A zone index and a block page with everything that makes a page wide: long ids and reasons,
    a failed block with a long path, warnings, raw WKT, sensor attributes, side views."""
    qa = tmp_path_factory.mktemp("zone") / "qa"
    pts = make_block(towers_at=((X0 + 60, Y0 + 60), (X0 + 150, Y0 + 120), (X0 + SIZE - 1.0, Y0 + 30)))
    gdf = towers_of(pts)
    gdf["tower_id"] = [f"T_a_very_long_zone_name_for_a_tower_{i:06d}" for i in range(len(gdf))]
    hood = {
        tid: {"x": pts["x"], "y": pts["y"], "z": pts["z"], "tower": pts["classification"] == 15}
        for tid in gdf["tower_id"]
    }
    _, preds = metas()
    preds[0]["model"] = {
        "name": "towerpipe-full",
        "version": "2",
        "feature_set": "full",
        "sha256": "ab" * 32,
        "choice": {"mode": "auto", "reason": "every sensor attribute of the zone is usable"},
    }
    long_path = "/data/flights/" + "x" * 180 + "/block.laz"
    summary = {
        "crs_wkt": 'PROJCRS["ETRS89 / UTM zone 31N",BASEGEOGCRS["ETRS89",' * 30,
        "path": long_path,
        "attributes": {"returns": {"valid": False, "reason": "return numbers all 0"}},
        "degenerate_attributes": ["returns"],
    }
    report(
        qa,
        "b1",
        zone="z1",
        pred_metas=preds,
        towers=gdf,
        classified=pts,
        truth=pts["classification"].copy(),
        stats=summary,
        warnings=[f"tile 0_0: neighbour block {long_path} could not be read"],
        neighbourhoods=hood,
        timings={"infer_tile": 12.5},
    )
    index = zone_index(
        qa / "index.html",
        [qa / "b1.json"],
        zone="z1",
        failures={"b2": f"split_block: InputError: {long_path}: not a readable LAS/LAZ file"},
        block_bounds={"b2": (X0 + SIZE, Y0, X0 + 2 * SIZE, Y0 + SIZE)},
    )
    assert index["totals"]["failed"] == 1
    return qa


@pytest.mark.parametrize("page", ["index.html", "b1.html"])
def test_page_loads_clean_and_fits_1280px(browser, pages, page):
    check = browser.check(pages / page, PAGE_WIDTH)
    assert check.title.startswith("QA")
    assert check.client_width <= PAGE_WIDTH
    assert check.ok, "\n".join(check.problems())


def test_check_sees_console_errors_and_overflow(browser, tmp_path):
    bad = tmp_path / "bad.html"
    bad.write_text(
        "<!DOCTYPE html><html><head><title>bad</title></head><body>"
        "<table><tr><td style='white-space:nowrap'>" + "wide " * 400 + "</td></tr></table>"
        "<script>console.error('boom'); undefined_function();</script></body></html>"
    )
    check = browser.check(bad, PAGE_WIDTH)
    assert check.overflow_px > 0
    assert any("boom" in e for e in check.console_errors)
    assert any("undefined_function" in e for e in check.console_errors)
    assert not check.ok


def test_screenshot(browser, pages, tmp_path):
    png = browser.screenshot(pages / "index.html", tmp_path / "index.png", PAGE_WIDTH, 800)
    from PIL import Image

    with Image.open(png) as im:
        assert im.size == (PAGE_WIDTH, 800)
        # not blank: the page's colours are there
        assert len(np.unique(np.asarray(im.convert("L")))) > 20
