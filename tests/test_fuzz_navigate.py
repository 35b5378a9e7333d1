"""The navigation fuzz section: generated damaged inputs to pivot, spin, register, assess and
points give an answer that adds up or one error line, never a crash or garbage; and its
outcome rule catches an answer from rotation blocks that are not rotations."""

from openemt_fuzz import _fuzznavigate as F


def test_generated_navigation_cases_have_no_findings():
    r = F.fuzz_navigate(40, seed=3)
    assert r["cases"] == 40 and r["findings"] == 0, r["examples"]
    outcomes = {k for c in r["by_command"].values() for k in c}
    assert {"ok", "refused"} <= outcomes
    assert r["max_seconds_per_case"] > 0


def test_outcome_rule_flags_answers_that_cannot_be_right():
    ok = '{"tip_mm": [1, 2, 3], "pivot_mm": [0, 0, 0], "rms_mm": 0.1, "n": 8, "dropped": {}}'
    expect = {"rows": 8, "damage": []}
    assert F._outcome(["pivot"], expect, 0, ok, "") == "ok"
    assert F._outcome(["pivot"], {**expect, "damage": ["rotation"]}, 0, ok, "") == "garbage"
    assert F._outcome(["pivot"], {**expect, "rows": 9}, 0, ok, "") == "garbage"
    assert F._outcome(["pivot"], expect, 0, ok.replace("0.1", "NaN"), "") == "garbage"
    assert F._outcome(["pivot"], expect, 2, "", "error: expected x, got y\n") == "refused"
    assert F._outcome(["pivot"], expect, 2, "", "error: a\nmore\n") == "vague"
    assert F._outcome(["pivot"], expect, 1, "", "Traceback\n") == "crash"
