"""The report explains itself: a computed reason for every failed or surprising row, every
symbol defined, one coil naming and one unit per quantity, fixed parameters marked fixed, a
colour bar on every colour-mapped plot; rendered in headless Chromium."""

import re

import numpy as np
import pytest
from _report_checks import defined_symbols, shown_symbols
from chromium_render import render

from openemt.calibrate import fit
from openemt.geometry import ground_truth_poses
from openemt.paper import (
    explain_rows,
    parameter_rows,
    parameters_against_truth,
)
from openemt.paper._reasons import (
    coil_spread,
    concentric_misfit,
    concentric_reason,
    correction_reason,
)
from openemt.report import GLOSSARY, Report, characterization_report, error_map_figure
from openemt.simulate import get_preset, simulate, truth_calibration


@pytest.fixture(scope="module")
def tracker():
    """The dipole-approximating source (coils 45 mm off centre): an XYZ fit from the truth, a
    concentric fit from that, and a third of the home-fixture ld test rows."""
    pre = get_preset("dipole-approx")
    truth = truth_calibration(pre)
    md = simulate(pre, "md", snr_db=80, seed=3)
    cal = fit(md, truth, "XYZ", warn=False).calibration
    conc = fit(md, cal, "concentric", warn=False).calibration
    ld = simulate(pre, "ld", source_fixtures=pre.source_fixtures[0],
                  sensor_fixtures=pre.sensor_fixtures[0], snr_db=80, seed=4)
    ld = ld.select(np.arange(len(ld)) % 3 == 0)
    D = ground_truth_poses(cal.source_fixture, cal.stage_fixture, cal.sensor_fixture,
                           ld.source_fixture, ld.stage, ld.sensor_fixture)
    return truth, cal, conc, ld, D


@pytest.fixture(scope="module")
def built(tracker):
    """The report of the XYZ fit with its concentric calibration, and its figures."""
    _, cal, conc, ld, _ = tracker
    figures = []
    original = Report.figure

    def record(self, fig, caption=""):
        figures.append((caption, _colour_mapped(fig), _n_colorbars(fig)))
        return original(self, fig, caption)

    Report.figure = record
    try:
        b = characterization_report(ld, cal, concentric=conc)
    finally:
        Report.figure = original
    return b, figures


def _n_colorbars(fig):
    return sum(ax.get_label() == "<colorbar>" for ax in fig.axes)


def _colour_mapped(fig):
    """Whether a plot colours its marks by value: a collection with a data array, or with
    marks in more than two colours."""
    for ax in fig.axes:
        if ax.get_label() == "<colorbar>":
            continue
        for c in ax.collections:
            if c.get_array() is not None:
                return True
            for colours in (c.get_facecolors(), c.get_edgecolors()):
                if len(np.unique(np.round(np.asarray(colours), 3), axis=0)) > 2:
                    return True
    return False


# -- reasons ---------------------------------------------------------------------------------

def test_concentric_row_reason_is_derived_from_the_models(tracker, built):
    _, cal, conc, ld, D = tracker
    acc = built[0].summary["accuracy"]
    row = acc["concentric + Kim18"]
    assert row["n_invalid"] == row["n"] == len(ld)
    spread = coil_spread(cal.model.L_so) * 1e3
    assert spread > 40                        # the preset's coils are 45 mm off centre
    assert row["reason"].startswith("expected: Kim18 assumes concentric coils")
    assert f"source coils up to {spread:.1f} mm apart" in row["reason"]
    misfit = concentric_misfit(cal.model, conc.model, D)
    assert f"in {int((misfit >= 1e-5).sum())} of {len(ld)} rows" in row["reason"]
    assert acc["calibration"]["n_invalid"] == 0 and acc["calibration"]["reason"] is None


def test_concentric_reason_only_where_the_approximation_explains_it(tracker):
    _, cal, conc, _, D = tracker
    # the same coils moved to within a few micrometres of one point: the concentric model of
    # them explains their noise-free couplings, so invalid rows need another reason
    near = cal.model.replace(L_so=cal.model.L_so * 1e-4, L_se=cal.model.L_se * 1e-4)
    at_one_point = near.replace(L_so=np.zeros((3, 3)), L_se=np.zeros((3, 3)))
    assert concentric_misfit(near, at_one_point, D).max() < 1e-5
    assert concentric_reason(near, at_one_point, D, n_invalid=len(D)) is None
    rows = {"conc": {"trans_rms_mm": 3.0, "n": len(D), "n_invalid": 7}}
    explain_rows(rows, model=near, poses=D, concentric=at_one_point, concentric_key="conc")
    assert rows["conc"]["reason"].startswith(f"7 of {len(D)} rows have a solution residue")
    # nothing failed, or the tested model is not concentric: no concentric reason
    assert concentric_reason(cal.model, conc.model, D, n_invalid=0) is None
    assert concentric_reason(cal.model, cal.model, D, n_invalid=len(D)) is None


def test_correction_reason():
    assert correction_reason({"trans_rms_mm": 0.2}, {"trans_rms_mm": 0.1}) is None
    reason = correction_reason({"trans_rms_mm": 0.2}, {"trans_rms_mm": 0.31})
    assert "from 0.200 to 0.310 mm" in reason


# -- the HTML ----------------------------------------------------------------------------------

def test_every_symbol_is_defined_and_rendered(built, tmp_path):
    b, _ = built
    out = tmp_path / "report.html"
    b.write(out)
    text = out.read_text()
    shown, defined = shown_symbols(text), defined_symbols(text)
    assert {"L_so", "M_so", "L_se", "M_se", "F_so", "F_st", "F_se", "n_invalid",
            "std_error", "status"} <= shown
    assert shown <= defined, f"undefined: {shown - defined}"
    assert defined <= set(GLOSSARY)
    assert "MacLachlan et al. 2025, eq. 6" in text and "fixture chain" in defined
    n, ok, dom = render(out, tmp_path)
    assert (n, ok) == (2, 2), f"images total/decoded = {n}/{ok}"
    assert "Symbols and terms" in dom and "expected: Kim18 assumes concentric coils" in dom


def test_fixed_parameters_are_marked_fixed(tracker, built):
    _, cal, _, _, _ = tracker
    rows = {r["parameter"]: r for r in parameter_rows(cal)}
    for name in ("L_so[x, coil Z]", "L_se[z, coil Z]", "M_so[y, coil Z]", "M_se[x, coil Z]"):
        assert rows[name]["status"] == "fixed (gauge)" and np.isnan(rows[name]["std_error"])
    # XYZ holds the X moments' y components, the source reference gain and the source fixture
    for name in ("M_so[y, coil X]", "M_se[y, coil X]", "M_so[z, coil Z]", "F_so.x"):
        assert rows[name]["status"] == "fixed" and np.isnan(rows[name]["std_error"])
    fitted = [r for r in rows.values() if r["status"] == "fitted"]
    assert len(fitted) == cal.stats["n_free"]
    assert all(r["std_error"] > 0 for r in fitted)    # fixtures included (F_st, F_se)
    assert rows["F_st.y"]["status"] == "fitted"
    # in the HTML: a fixed parameter shows its status and no standard error, never 0.000000
    cells = re.findall(r'<tr><td class="label">([LMF]_s[oet][^<]*)</td><td class="">[^<]*</td>'
                       r'<td class="">[^<]*</td><td class="">([^<]*)</td><td class="">([^<]*)'
                       r"</td>", built[0].report.html())
    assert len(cells) == len(rows)
    for name, se, status in cells:
        assert status == rows[name]["status"]
        assert (se == "–") if status.startswith("fixed") else float(se) > 0, name


def test_one_coil_naming_and_one_unit_per_quantity(tracker):
    truth, cal, _, _, _ = tracker
    plain, against = parameter_rows(cal), parameters_against_truth(cal, truth)
    assert [r["parameter"] for r in plain] == [r["parameter"] for r in against]
    units = {}
    for r in against:
        m = re.fullmatch(r"(L_so|M_so|L_se|M_se)\[[xyz], coil [XYZ]\]|(F_s[oet])\.(r?)[xyz]",
                         r["parameter"])
        assert m, r["parameter"]
        quantity = m.group(1)[0] if m.group(1) else ("rotation" if m.group(3) else "L")
        units.setdefault(quantity, set()).add(r["unit"])
    assert units == {"L": {"mm"}, "M": {"gain"}, "rotation": {"deg"}}
    row = next(r for r in against if r["parameter"] == "L_so[x, coil X]")
    assert row["value"] == pytest.approx(cal.model.L_so[0, 0] * 1e3)
    assert row["truth"] == pytest.approx(truth.model.L_so[0, 0] * 1e3)


def test_every_colour_mapped_plot_has_a_colour_bar(built):
    _, figures = built
    assert len(figures) == 2
    for caption, mapped, n_bars in figures:
        assert n_bars == (1 if mapped else 0), caption
    vectors = next(f for f in figures if f[0].startswith("Translation error vectors"))
    assert vectors[1:] == (True, 1)           # the 3-D error plot is coloured and has its bar
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.1, 0.1, (20, 2)), np.full(20, 0.1)]
    fig = error_map_figure(pts, rng.normal(scale=1e-3, size=(20, 3)))
    assert _colour_mapped(fig) and _n_colorbars(fig) == 1
