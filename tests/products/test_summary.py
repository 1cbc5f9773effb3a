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
        "localrule zone_results:\n    input: work/z1/published.json\n    output: results/z1/\n    jobid: 0\n"
        "rule model_results:\n    output: results/models/m1/\n"
        "rule split_block:\n    output: work/z3/cache/b1\n    jobid: 3\n    wildcards: zone=z3, block=b1\n"
        "Finished jobid: 0 (Rule: zone_results)\nFinished jobid: 3 (Rule: split_block)\n"
    )
    assert zones_in_log(log) == ["z1"]
    # a night that changed blocks of a published zone assembles it (results/<zone>/ is swapped
    # in by the assembly: zone_results does not run); an assembly that failed does not count
    log.write_text(
        "localrule assemble_zone:\n    input: /w/z4/out/b.laz\n    output: /w/z4/published.json\n"
        "    log: /w/z4/logs/assemble_zone.log\n    jobid: 4\n    reason: Input files updated\n"
        "    wildcards: zone=z4\n    resources: tmpdir=/tmp\n"
        "localrule assemble_zone:\n    output: /w/z5/published.json\n    jobid: 5\n    wildcards: zone=z5\n"
        "Finished jobid: 4 (Rule: assemble_zone)\nError in rule assemble_zone:\n    jobid: 5\n"
    )
    assert zones_in_log(log) == ["z4"]
    print_summary(["z1"], tmp_path)
    assert capsys.readouterr().out.startswith("towerpipe: zone z1: 6 towers")
