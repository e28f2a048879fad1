"""`replanner bench block`: the arm sent across a blocked transfer path on a simulated clock."""

from __future__ import annotations

import json

from tests.test_cli import replanner


def test_bench_block_json_reports_each_policy_and_keeps_the_separation():
    out = replanner("bench", "block", "--poses", "1", "--boxes", "1", "--hold", "2", "--policy", "replan", "--json")
    assert out.returncode == 0, out.stderr[-3000:]
    r = json.loads(out.stdout)
    assert r["bench"] == "block" and r["policies"] == ["replan"] and r["unblocked"]["duration_s"] > 0
    p = r["replan"]
    assert [c["kind"] for c in p["cases"]] == ["forearm", "box"]
    assert p["collisions"] == 0 and p["separation_below_sp"] == 0, p["cases"]
    assert p["forearm_reached"] == 1.0  # a forearm taken away after 2 s: the arm gets there, round it or after it


def test_bench_block_names_a_bad_policy():
    out = replanner("bench", "block", "--policy", "teleport")
    assert out.returncode != 0 and "--policy must be one of" in out.stderr + out.stdout
