"""Tests of towerpipe.products.summary: the end-of-run lines."""

from __future__ import annotations

import json

from towerpipe.products.summary import print_summary, zone_summary, zones_in_log


def test_zone_summary_and_zones_in_log(tmp_path, capsys):
    qa = tmp_path / "z1" / "qa"
    qa.mkdir(parents=True)
    (qa / "index.json").write_text(json.dumps({"totals": {"towers": 6, "blocks": 4, "failed": 1, "look": 1}}))
    assert zone_summary("z1", tmp_path) == (
        f"zone z1: 6 towers in 4 blocks, 1 failed, 1 needs a look; QA index: {tmp_path}/z1/qa/index.html"
    )
    assert "no QA index" in zone_summary("z2", tmp_path)
    log = tmp_path / "run.log"
    log.write_text(
        "rule assemble_zone:\n    output: results/z1/\n    jobid: 0\n"
        "rule model_results:\n    output: results/models/m1/\n"
        "rule split_block:\n    output: work/z3/cache/b1\n"
    )
    assert zones_in_log(log) == ["z1"]
    print_summary(["z1"], tmp_path)
    assert capsys.readouterr().out.startswith("towerpipe: zone z1: 6 towers")
