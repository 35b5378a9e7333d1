"""Hostile references for ``openemt collect``: damaged OpenIGTLink streams and reference CSVs are
counted by reason and never kept as poses; mismatched references are refused (a few generated
cases; the long run is ``openemt bench fuzz``, section openemt_fuzz._fuzzreference)."""

from __future__ import annotations

import numpy as np
import pytest
from openemt_fuzz import _fuzzreference as F

from openemt._errors import InputError
from openemt.align import time_offset_scan
from openemt.collect import check_pairing, read_reference_csv, rigid_rows, simulated_motion


@pytest.mark.parametrize("kind,reason", [("crc_some", "crc"), ("not_rotation", "not_a_rotation"),
                                         ("status_invalid", "transform_status_invalid"),
                                         ("valid_false", "transform_not_valid"),
                                         ("bad_metadata", "metadata_sizes")])
def test_client_counts_damaged_messages_and_keeps_only_rigid_poses(kind, reason):
    out = F._client_case(kind, 3, 20.0)
    assert out["finding"] is None, out
    assert out["drops"].get(reason, 0) > 0 and out["kept"] > 100, out


@pytest.mark.parametrize("kind", ["huge_size", "random_header", "truncated"])
def test_client_ends_on_a_broken_stream_without_an_exception(kind):
    out = F._client_case(kind, 5, 20.0)
    assert out["finding"] is None, out
    assert out["kept"] > 0
    if kind == "truncated":
        assert out["drops"] == {"truncated": 1}, out
    else:
        assert out["error"] is not None and "expected" in out["error"], out


@pytest.mark.parametrize("kind,reason", [("nan", "not_finite"), ("empty", "empty_field"),
                                         ("wrong_length", "wrong_length"),
                                         ("zero_quaternion", "not_a_rotation"),
                                         ("inf_time", "not_finite"), ("nul", "nul_or_bad_byte"),
                                         ("not_a_number", "not_a_number"),
                                         ("glitch", "time_glitch"), ("jump", "clock_jump")])
def test_reference_csv_rows_dropped_by_reason(tmp_path, kind, reason):
    t, P = table = read_reference_csv(F.csv_case(kind, tmp_path, 1, seconds=10))
    assert table.drops.get(reason, 0) > 0, table.drops
    assert rigid_rows(P).all() and np.all(np.diff(t) > 0)
    if kind == "jump":
        assert table.jumped == pytest.approx(1000.0, abs=0.02)
        assert table.drops["after_clock_jump"] > 100


def test_reference_csv_in_milliseconds_is_refused(tmp_path):
    with pytest.raises(InputError, match="milliseconds"):
        read_reference_csv(F.csv_case("milliseconds", tmp_path, 1, seconds=10))


def test_offset_correlation_is_a_correlation():
    rng = np.random.default_rng(4)
    for _ in range(20):
        a, b = rng.standard_normal(500) ** 2, rng.standard_normal(800)
        a[rng.integers(0, 500, 50)] = 1e6                  # spikes that broke the old sums
        e = time_offset_scan(np.arange(500) * 0.002, a, 7 + np.arange(800) * 0.002, b)
        assert -1.0 <= e.correlation <= 1.0 and 0.0 <= e.confidence <= 1.0


def test_pairing_refuses_shifted_dwells_and_another_unit():
    from openemt.geometry import invert

    m = simulated_motion("robot", 12, seed=1)
    A = m.poses                                           # the tracker's poses
    B = invert(m.Y) @ A @ m.X                              # what the reference held there
    assert check_pairing(A, B)["ok"]
    with pytest.raises(InputError, match="rotations between dwells"):
        check_pairing(A, np.roll(B, 1, axis=0))            # paired with the wrong dwells
    mm = B.copy()
    mm[:, :3, 3] *= 1e-3                                   # metres read as millimetres
    with pytest.raises(InputError, match="another length unit"):
        check_pairing(A, mm)


@pytest.mark.parametrize("source,kind", [("csv", "other_motion"), ("server", "metres_as_mm")])
def test_collect_refuses_a_mismatched_reference(tmp_path, source, kind):
    out = F._collect_case(kind, 1, source, tmp_path, 120)
    assert out["finding"] is None and out["outcome"] == "refused", out


def test_transform_bodies_of_the_wrong_size_are_not_read():
    from openemt.collect import parse_transform_body

    assert parse_transform_body(1, b"\0" * 10) == (None, "transform_body_size")
    assert parse_transform_body(2, b"\0" * 10) == (None, "transform_body_size")
    good = F.transform_message(np.eye(4), 5.0, version=2, meta={"TransformStatus": "OK"})[58:]
    M, meta = parse_transform_body(2, good)
    assert np.allclose(M, np.eye(4)) and meta == {"TransformStatus": "OK"}
    assert parse_transform_body(2, good[:-1])[0] is None            # sizes do not add up
