"""Tests of towerpipe.evaluation.trace: the table of where each true tower was lost, and its
errors (the stages themselves: tests/workflow/test_e2e.py on the CI scene, tests/towers for the trace)."""

from __future__ import annotations

import pytest

from towerpipe.errors import InputError
from towerpipe.evaluation.trace import RULE_NAMES, trace_table, trace_zone
from towerpipe.towers.extract import TRACE_RULES


def _row(tid: str, stage: str, value: float = float("nan"), cluster: int = 0) -> dict:
    return {
        "tower_id": tid,
        "design": "small_lattice",
        "height_m": 16.5,
        "n_points": 180,
        "max_prob": 0.24,
        "stage": stage,
        "value": value,
        "cluster_points": cluster,
    }


def test_every_rule_of_a_trace_has_a_reading():
    assert set(RULE_NAMES) == set(TRACE_RULES)


def test_the_table_lists_the_missed_towers_first_and_counts_the_found():
    rows = [_row("2", "found"), _row("10", "core", 0.24, 105), _row("9", "not segmented")]
    lines = trace_table(rows).splitlines()
    body = [line for line in lines if line.startswith("| ") and not line.startswith("| tower")]
    assert [line.split("|")[1].strip() for line in body] == ["9", "10", "2"]
    assert RULE_NAMES["core"] in body[1] and "0.240" in body[1] and "| 105 |" in body[1]
    assert lines[-1] == "1 of 3 true towers found."


def test_a_zone_never_run_names_the_run_to_do(tmp_path):
    with pytest.raises(InputError, match=r"snakemake --cores 2 results/z1/"):
        trace_zone(tmp_path, "z1", tmp_path, inference={"threshold": 0.3}, towers={})
