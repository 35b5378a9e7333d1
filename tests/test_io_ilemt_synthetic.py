"""ILEMT .dat parsing, sign options, compensation and bad input on small synthetic files."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from openemt.io import compensate_stage, import_ilemt_folder, parse_sign_options, read_ilemt_dat


def _cfmt(z: complex) -> str:
    return f"{z.real:+.9f}{z.imag:+.9f}i"


def _write_dat(path, stage_mm_deg, hr, lr, sep="\t", fmt=_cfmt):
    lines = []
    for s, h, lo in zip(stage_mm_deg, hr, lr):
        # file value k = source k % 3 into sensor k // 3, i.e. C.T flattened
        vals = [f"{v:.5f}" for v in s] + [fmt(z) for z in h.T.ravel()] + [fmt(z) for z in lo.T.ravel()]
        lines.append(sep.join(vals))
    path.write_text("\n".join(lines) + "\n")


def _random_rows(rng, n):
    stage = np.zeros((n, 6))
    stage[1:-1, :3] = np.round(rng.uniform(-50, 50, (n - 2, 3)), 5)
    stage[1:-1, 5] = rng.choice([-90.0, -45.0, 0.0, 45.0, 90.0], n - 2)
    hr = np.round(rng.normal(size=(n, 3, 3)), 9) + 1j * np.round(rng.normal(size=(n, 3, 3)) * 1e-3, 9)
    hr[-1] = hr[0]                              # no drift
    lr = np.round(rng.normal(size=(n, 3, 3)) * 1e-2, 9) + 1j * np.round(
        rng.normal(size=(n, 3, 3)) * 1e-5, 9)
    return stage, hr, lr


@pytest.fixture
def folder(tmp_path):
    rng = np.random.default_rng(7)
    data = {}
    for name in ("soYoutZup_seYoutZup_md.dat", "soXoutZup_seZinYup_md.dat",
                 "soYoutZup_seZinXdown_ld.dat"):
        data[name] = _random_rows(rng, 9)
        _write_dat(tmp_path / name, *data[name])
    (tmp_path / "notes.dat").write_text("not data\n")           # does not match the name rule
    return tmp_path, data


def test_layout_units_and_concatenation(folder):
    path, data = folder
    ds = import_ilemt_folder(path, compensate_stage=False)
    assert ds.files == tuple(sorted(data))
    for i, name in enumerate(ds.files):
        stage, hr, lr = data[name]
        rows = ds.file_index == i
        np.testing.assert_array_equal(ds.couplings[rows], hr)     # C[source, sensor]
        np.testing.assert_array_equal(ds.extra["couplings_lr"][rows], lr)
        np.testing.assert_allclose(ds.stage[rows, :3], stage[:, :3] / 1000, rtol=1e-15)
        np.testing.assert_allclose(ds.stage[rows, 3:], np.deg2rad(stage[:, 3:]), rtol=1e-15)
    assert set(ds.source_fixture) == {"YoutZup", "XoutZup"}
    assert list(ds.pattern).count("ld") == 9
    assert ds.meta["provenance"]["signs_from"] == "none"
    assert "source" not in ds.meta                 # no local_cal_options.m, no names


def test_comma_g_format_with_missing_imaginary_part(tmp_path):
    rng = np.random.default_rng(3)
    stage, hr, lr = _random_rows(rng, 5)
    hr[2, 1, 0] = 0.25                            # zero imaginary part: written without "i"

    def gfmt(z):
        return f"{z.real:g}" if z.imag == 0 else f"{z.real:g}{z.imag:+g}i"

    _write_dat(tmp_path / "soYoutZup_seYoutZup_mdtrans.dat", stage, hr, lr, sep=",", fmt=gfmt)
    ds = read_ilemt_dat(tmp_path / "soYoutZup_seYoutZup_mdtrans.dat", compensate_stage=False)
    np.testing.assert_allclose(ds.couplings, hr, rtol=1e-5, atol=1e-9)
    assert ds.couplings[2, 1, 0] == 0.25
    assert ds.pattern[0] == "mdtrans"


def test_sign_rules_first_match_and_outer_product(folder):
    path, data = folder
    so = [("XoutZup", (-1, 1, 1)), ("so.*_se", (1, -1, 1))]
    se = [("ZinXdown", (1, 1, -1))]
    ds = import_ilemt_folder(path, source_signs=so, sensor_signs=se, compensate_stage=False)
    for i, name in enumerate(ds.files):
        rows = ds.file_index == i
        s_so = np.array([-1, 1, 1]) if "XoutZup" in name else np.array([1, -1, 1])
        s_se = np.array([1, 1, -1]) if "ZinXdown" in name else np.ones(3)
        np.testing.assert_array_equal(ds.couplings[rows], data[name][1] * np.outer(s_so, s_se))
        np.testing.assert_array_equal(ds.source_signs[rows][0], s_so)
        np.testing.assert_array_equal(ds.sensor_signs[rows][0], s_se)
    assert ds.meta["provenance"]["source_signs"] == [["XoutZup", [-1, 1, 1]], ["so.*_se", [1, -1, 1]]]
    with pytest.raises(ValueError, match="signs"):
        import_ilemt_folder(path, source_signs=[("x", (1, 2, 1))])


def test_sign_options_file_is_used_and_parsed(tmp_path, folder):
    path, data = folder
    (path / "local_cal_options.m").write_text(
        "options.source = 'My ''cube''';  % trailing comment\n"
        "options.sensor = 'premo';\n"
        "%{\n options.source_signs = { 'md' [1 1 1] };\n%}\n"
        "% options.source_signs = { 'ld' [1 1 1] };\n"
        "options.source_signs = {\n"
        "    'soXoutZup_seZinYup_(md|ld).dat' [-1 -1 1]   % 50% sure\n"
        "    'ld', [1, -1, 1]; ...\n"
        "    };\n"
        "options.sensor_signs = {};\n")
    so, se = parse_sign_options(path / "local_cal_options.m")
    assert so == [("soXoutZup_seZinYup_(md|ld).dat", (-1.0, -1.0, 1.0)), ("ld", (1.0, -1.0, 1.0))]
    assert se == []
    ds = import_ilemt_folder(path, compensate_stage=False)
    assert ds.meta["source"]["name"] == "My 'cube'"
    assert ds.meta["provenance"]["signs_from"] == "local_cal_options.m"
    name = "soXoutZup_seZinYup_md.dat"
    rows = ds.file_index == ds.files.index(name)
    np.testing.assert_array_equal(ds.couplings[rows], data[name][1] * np.array([-1, -1, 1])[:, None])
    # explicit empty lists override the file
    raw = import_ilemt_folder(path, source_signs=[], sensor_signs=[], compensate_stage=False)
    np.testing.assert_array_equal(raw.couplings[rows], data[name][1])


@pytest.mark.parametrize("text, match", [
    ("options.source_signs = [1 1 1];", "expected `options.source_signs = {"),
    ("options.source_signs = { 'md' [1 1 1] junk };", "unparsable"),
    ("options.source_signs = { 'md' [1 2 1] };", "signs of \\+1/-1"),
    ("options.source_signs = { 'md(' [1 1 1] };", "regular expression"),
    ("options.source_signs = { 'md' [1 1 1]", "closing"),
])
def test_sign_options_malformed(tmp_path, text, match):
    f = tmp_path / "local_cal_options.m"
    f.write_text(text + "\n")
    with pytest.raises(ValueError, match=match) as exc:
        parse_sign_options(f)
    assert "local_cal_options.m" in str(exc.value) and "\n" not in str(exc.value)


def test_compensation_properties():
    rng = np.random.default_rng(11)
    s = np.zeros((50, 6))
    s[:, :3] = rng.uniform(-60, 60, (50, 3))   # includes extrapolation beyond the tables
    s[:, 5] = rng.uniform(-180, 180, 50)
    out = compensate_stage(s)
    np.testing.assert_array_equal(compensate_stage(np.zeros(6)), np.zeros(6))   # null stays 0
    np.testing.assert_array_equal(out[:, 3:], s[:, 3:])
    loop = np.array([compensate_stage(row) for row in s])                        # batch vs loop
    np.testing.assert_allclose(out, loop, rtol=0, atol=1e-12)
    # the XY error is rotated by Rz: its length does not depend on the angle
    s0 = s.copy()
    s0[:, 5] = 0
    e0 = compensate_stage(s0)[:, :2] - s0[:, :2]
    e = out[:, :2] - s[:, :2]
    np.testing.assert_allclose(np.hypot(*e.T), np.hypot(*e0.T), rtol=1e-12)
    # linear extrapolation by the end segment: Y->Y beyond -50 continues the -25..-50 slope
    y = compensate_stage([[0, -60, 0, 0, 0, 0]])[0, 1]
    slope = (-0.350 - -0.310) / (-50 - -25)
    assert y == pytest.approx(-60 + (-0.350 + slope * (-10)) - (-0.200), abs=1e-12)
    # Z -> X and Z -> Z at the table end -46 mm
    z = compensate_stage([0, 0, -46.0, 0, 0, 0])
    assert z[0] == pytest.approx(-0.140 - 0.050, abs=1e-12)
    assert z[2] == pytest.approx(-46.0 + 0.0836, abs=1e-12)   # ZZ(-46) - ZZ(0), ZZ(0) interpolated
    with pytest.raises(ValueError, match=r"shape \(N, 6\)"):
        compensate_stage(np.zeros((3, 5)))


def test_drift_warning(tmp_path):
    rng = np.random.default_rng(5)
    stage, hr, lr = _random_rows(rng, 6)
    hr[-1] = hr[0] + 2e-4
    _write_dat(tmp_path / "soYoutZup_seYoutZup_md.dat", stage, hr, lr)
    with pytest.warns(UserWarning, match="drift"):
        read_ilemt_dat(tmp_path / "soYoutZup_seYoutZup_md.dat")
    hr[-1] = hr[0] + 5e-5
    _write_dat(tmp_path / "soYoutZup_seYoutZup_md.dat", stage, hr, lr)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_ilemt_dat(tmp_path / "soYoutZup_seYoutZup_md.dat")


def _good_file(tmp_path, name="soYoutZup_seYoutZup_md.dat"):
    rng = np.random.default_rng(1)
    _write_dat(tmp_path / name, *_random_rows(rng, 4))
    return tmp_path / name


def test_bad_field_count_names_file_and_line(tmp_path):
    f = _good_file(tmp_path)
    lines = f.read_text().splitlines()
    lines[2] = "\t".join(lines[2].split("\t")[:23])
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"soYoutZup_seYoutZup_md.dat: line 3: expected 24 "
                                         r"fields, got 23"):
        import_ilemt_folder(tmp_path)


def test_unparsable_number_names_file_line_and_field(tmp_path):
    f = _good_file(tmp_path)
    lines = f.read_text().splitlines()
    parts = lines[1].split("\t")
    parts[8] = "+0.1x+0.2i"
    lines[1] = "\t".join(parts)
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"md.dat: line 2: field 9: expected a complex number"):
        read_ilemt_dat(f)
    parts[8] = "+0.1+0.2i"
    parts[0] = "abc"
    lines[1] = "\t".join(parts)
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"line 2: field 1: expected a real number, got 'abc'"):
        read_ilemt_dat(f)


def test_truncated_and_empty_files(tmp_path):
    f = _good_file(tmp_path)
    text = f.read_text()
    f.write_text(text[: len(text) // 2 - 7])         # cut mid-line
    with pytest.raises(ValueError, match=r"md.dat: line 2: (expected 24 fields|field \d+: expected)"):
        read_ilemt_dat(f)
    f.write_text("")
    with pytest.raises(ValueError, match="empty file"):
        read_ilemt_dat(f)
    f.write_bytes(b"\x00\xff\xfe")
    with pytest.raises(ValueError, match="ASCII"):
        read_ilemt_dat(f)


def test_unknown_fixture_code_names_file(tmp_path):
    _good_file(tmp_path, "soYoutYup_seYoutZup_md.dat")
    with pytest.raises(ValueError, match=r"soYoutYup_seYoutZup_md.dat: unknown source fixture "
                                         r"code 'YoutYup'"):
        import_ilemt_folder(tmp_path)
    f = _good_file(tmp_path, "weird.dat")
    with pytest.warns(UserWarning, match="home fixtures"):
        ds = read_ilemt_dat(f, source_signs=[], sensor_signs=[])
    assert ds.source_fixture[0] == "YoutZup" and ds.pattern[0] == ""
    ds = read_ilemt_dat(f, source_fixture="XoutZup", sensor_fixture="ZinYup", pattern="md")
    assert (ds.source_fixture[0], ds.sensor_fixture[0], ds.pattern[0]) == ("XoutZup", "ZinYup", "md")


def test_empty_or_missing_folder(tmp_path):
    with pytest.raises(ValueError, match="got none"):
        import_ilemt_folder(tmp_path)
    (tmp_path / "readme.dat").write_text("x")
    with pytest.raises(ValueError, match="got none"):
        import_ilemt_folder(tmp_path)
    with pytest.raises(FileNotFoundError, match="missing folder"):
        import_ilemt_folder(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="missing file"):
        read_ilemt_dat(tmp_path / "nope.dat")
