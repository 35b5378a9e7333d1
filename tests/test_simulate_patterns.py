"""Stage patterns against docs/ilemt-data.md#patterns and against the stage columns of the real files."""

from __future__ import annotations

import numpy as np
import pytest

from openemt.simulate import STAGE_Z_LIMIT, stage_pattern

# row counts stated in docs/ilemt-data.md#recordings, docs/ilemt-data.md#patterns (grid: 7 x 7 points of the Anser test grid)
DOC_COUNTS = {"sd": 86, "md": 142, "ld": 632, "sweep": 973, "mdtrans": 30, "ldtrans": 128,
              "source": 78, "grid": 49}


def to_mm_deg(stage):
    out = np.array(stage, dtype=np.float64)
    out[:, :3] *= 1e3
    out[:, 3:] = np.rad2deg(out[:, 3:])
    return out


def mesh_by_loops(values, key, rz_values):
    """docs/ilemt-data.md#patterns in words: null; per Rz (outer) the first grid point, the key point, then the rest of
    the grid with x fastest, then y, then z; null. Z = -50 logged as -46.2."""
    rows = [[0.0] * 6]
    for rz in rz_values:
        grid = [[x, y, z] for z in values for y in values for x in values]
        for p in [grid[0], list(key)] + grid[1:]:
            rows.append([p[0], p[1], max(p[2], -46.2), 0.0, 0.0, rz])
    rows.append([0.0] * 6)
    return np.array(rows)


@pytest.mark.parametrize("name", sorted(DOC_COUNTS))
def test_row_counts(name):
    s = stage_pattern(name)
    assert s.shape == (DOC_COUNTS[name], 6)
    assert np.all(s[:, 3:5] == 0.0)  # the stage has no Rx/Ry axes


def test_md_ld_order_follows_section_3():
    md = mesh_by_loops((-50.0, 0.0, 50.0), (-25.0, -50.0, -50.0), (-90, -45, 0, 45, 90))
    ld = mesh_by_loops((-50.0, -25.0, 0.0, 25.0, 50.0), (-37.5, -50.0, -50.0),
                       (-90, -45, 0, 45, 90))
    np.testing.assert_allclose(to_mm_deg(stage_pattern("md")), md, rtol=0, atol=1e-9)
    np.testing.assert_allclose(to_mm_deg(stage_pattern("ld")), ld, rtol=0, atol=1e-9)
    # the worked rows of docs/ilemt-data.md#worked-example: row 2 of an md file is (-50, -50, -46.2, 0, 0, -90)
    np.testing.assert_allclose(to_mm_deg(stage_pattern("md"))[1], [-50, -50, -46.2, 0, 0, -90],
                               atol=1e-9)


def test_trans_subsets_are_zero_rotation_rows():
    for full, sub in (("md", "mdtrans"), ("ld", "ldtrans")):
        f = stage_pattern(full)
        np.testing.assert_array_equal(stage_pattern(sub), f[np.all(f[:, 3:] == 0, axis=1)])


def test_sweep_layout():
    s = to_mm_deg(stage_pattern("sweep"))
    null_rows = np.flatnonzero(np.all(s == 0, axis=1))
    # nulls between the sweeps; the Rx and Ry "sweeps" are single zero rows (0-based 607, 609)
    np.testing.assert_array_equal(null_rows, [0, 101, 202, 303, 404, 505, 606, 607, 608, 609,
                                              610, 791, 972])
    lin = np.arange(-50.0, 50.0001, 0.5)
    np.testing.assert_allclose(s[1:202, 0], lin, atol=1e-9)
    np.testing.assert_allclose(s[203:404, 1], lin, atol=1e-9)
    np.testing.assert_allclose(s[405:606, 2], np.maximum(lin, -46.2), atol=1e-9)
    np.testing.assert_allclose(s[611:972, 5], np.arange(-90.0, 90.0001, 0.5), atol=1e-9)


def test_clip_z_option():
    assert stage_pattern("md")[:, 2].min() == pytest.approx(STAGE_Z_LIMIT, abs=1e-15)
    raw = stage_pattern("md", clip_z=False)
    assert raw[:, 2].min() == pytest.approx(-0.050, abs=1e-15)
    clipped = raw[:, 2] < STAGE_Z_LIMIT
    np.testing.assert_array_equal(stage_pattern("md")[~clipped], raw[~clipped])


def test_grid_pattern():
    g = stage_pattern("grid")
    xs, ys = np.unique(g[:, 0]), np.unique(g[:, 1])
    np.testing.assert_allclose(np.diff(xs), 0.04286, atol=1e-12)
    np.testing.assert_allclose(xs, ys, atol=0)
    assert xs.mean() == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_array_equal(g[:7, 1], g[0, 1])  # x fastest
    assert np.all(g[:, 2:] == 0)


def test_bad_name():
    with pytest.raises(ValueError, match="expected a stage pattern name"):
        stage_pattern("xl")


@pytest.mark.parametrize("name", ["md", "ld", "sweep", "mdtrans", "ldtrans", "source"])
def test_equals_real_stage_columns(ilemt_dir, name):
    path = ilemt_dir / f"soYoutZup_seYoutZup_{name}.dat"
    real = np.loadtxt(path, usecols=range(6), delimiter="," if "trans" in name else None)
    np.testing.assert_allclose(to_mm_deg(stage_pattern(name)), real, rtol=0, atol=1e-9)


def test_every_real_md_file_has_the_md_pattern(ilemt_dir):
    files = sorted(ilemt_dir.glob("so*_se*_md.dat"))
    assert len(files) == 6
    md = to_mm_deg(stage_pattern("md"))
    for f in files:
        np.testing.assert_allclose(np.loadtxt(f, usecols=range(6)), md, rtol=0, atol=1e-9)
