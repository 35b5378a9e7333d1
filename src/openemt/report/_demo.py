"""The ``openemt demo`` workflow: the whole pipeline on the simulated tracker, ending in an HTML
report.

1. simulate the ILEMT apparatus with finite-size coils as physical truth: calibration data (md
   pattern, the paper's six fixture combinations) and test data (ld pattern, home source fixture,
   three sensor fixtures), with measurement noise and stage position error;
2. calibrate the dipole model and the rig fixtures (mode ``XYZ``) from a start perturbed away
   from the truth, a concentric model (mode ``concentric``) whose Kim18 closed form starts the
   iterative solver, and the DLT output correction on the calibration data;
3. solve the test data with the compiled LM solver and score it against the rig's kinematics,
   as the paper does (MacLachlan et al. 2025, Table II): the dipole-equivalent truth, the start,
   the fit, the fit with the output correction, and the concentric model with Kim18 alone;
4. write the datasets, calibrations and a self-contained HTML report.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .._errors import InputError
from .._options import SILENT, option
from .._result import Result

__all__ = ["DemoOptions", "DemoResult", "run_demo"]

#: What to do after the demo (the last lines ``openemt demo`` prints; ``{out}`` its folder).
NEXT_STEPS = """\
next: the same steps one command at a time, then on your own tracker (docs/workflow.md walks
the whole path, README.md lists every command, each explains itself with --help):
  openemt calibrate {out}/calibration_data.h5 --from {out}/truth_calibration.json -o cal.json
      fit the model from a start (docs/calibration.md)
  openemt solve {out}/test_data.h5 --calibration cal.json -o poses.h5
      sensor poses from couplings (docs/solve.md)
  openemt track --source sim --preset {preset} --calibration cal.json --duration 5
      live poses served to 3D Slicer over OpenIGTLink (docs/live.md)"""


@dataclasses.dataclass(frozen=True)
class DemoOptions:
    """The simulated tracker of the demo (field metadata: the command-line help)."""

    preset: str = option("dipole-approx", "simulated source (default: dipole-approx, MacLachlan "
                         "et al. 2025's 3-coil source)", choices=("dipole-approx", "concentric"))
    output_dir: str = option("openemt-demo", "folder for the datasets, calibrations and report "
                             "(default: openemt-demo)", flag=("-o", "--output-dir"))
    snr_db: float = option(80.0, "measurement SNR in dB (default 80)")
    stage_error_um: float = option(107.0, "3-D RMS stage position error in um (default 107, the "
                                   "paper's stage uncertainty); per axis it is this / sqrt(3)")
    seed: int = option(1, "random seed (default 1)")


@dataclasses.dataclass(frozen=True)
class DemoResult(Result):
    """The demo's files, the accuracy of every calibration on the test rows, and the time of
    each step."""

    preset: str
    output_dir: str
    report: str
    n_calibration: int
    n_test: int
    snr_db: float
    stage_error_um: float
    seed: int
    rms_residue: float | None
    rows: dict
    n_figures: int
    seconds: dict

    def lines(self) -> list[str]:
        """The accuracy table, why a row failed, the times, the report and the next steps."""
        human = [f"openemt demo: simulated '{self.preset}' tracker -> {self.output_dir}/"]
        for k, v in self.rows.items():
            human.append(f"  {k:48s} {v['trans_rms_mm']:.3f} mm RMS  {v['rot_rms_deg']:.3f} "
                         "deg RMS" + (f"  ({v['n_invalid']} invalid)" if v["n_invalid"] else ""))
            if v.get("reason"):
                human.append(f"      why: {v['reason']}")
        steps = {k: v for k, v in self.seconds.items() if k != "total"}
        human.append("  seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in steps.items()))
        return human + [f"  report: {self.report}",
                        *NEXT_STEPS.format(out=self.output_dir, preset=self.preset).splitlines()]


def run_demo(o: DemoOptions, say=None) -> DemoResult:
    """Simulate, calibrate, correct, solve, score and report (module docstring); ``say`` hears
    each step before it runs."""
    from pathlib import Path

    from .._compile_notice import announce_compile, dipole_kernels

    if not np.isfinite(o.snr_db) or o.snr_db <= 0:
        raise InputError(f"expected --snr-db > 0, got {o.snr_db}")
    if not np.isfinite(o.stage_error_um) or o.stage_error_um < 0:
        raise InputError(f"expected --stage-error-um >= 0, got {o.stage_error_um}")
    say = say or SILENT
    out = Path(o.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    # the first line comes before any heavy import
    say(f"openemt demo: simulated '{o.preset}' tracker -> {out}/")

    from ..calibrate import (
        fit,
        fit_output_correction,
        get_mode,
        held_out_rows,
        perturb_calibration,
    )
    from ..io import write_calibration, write_dataset
    from ..paper import characterize_calibration, parameter_rows, truth_comparison_rows
    from ..simulate import get_preset, simulate, truth_calibration
    from ._glossary import glossary_section
    from ._sections import characterization_document, simulation_section

    seconds: dict[str, float] = {}
    t_all = t0 = time.perf_counter()

    def step(name):
        nonlocal t0
        seconds[name] = round(time.perf_counter() - t0, 3)
        t0 = time.perf_counter()

    # the first run compiles the solver kernels here, under a line of its own, not inside the
    # steps that use them (those it runs: its simulated couplings are real)
    if announce_compile(say, "solver kernels",
                        kernels=dipole_kernels(complex_couplings=False)):
        step("compile")

    preset = get_preset(o.preset)
    sigma = o.stage_error_um * 1e-6 / np.sqrt(3.0)
    say("simulating calibration data (md, six fixture combinations) and test data "
        "(ld, home source fixture) ...")
    cal_data = simulate(preset, "md", source_fixtures="all", sensor_fixtures="all",
                        snr_db=o.snr_db, stage_sigma=sigma, seed=o.seed)
    test_data = simulate(preset, "ld", source_fixtures=preset.source_fixtures[0],
                         sensor_fixtures="all", snr_db=o.snr_db, stage_sigma=sigma,
                         seed=o.seed + 1000)
    test_data = test_data.select(held_out_rows(test_data))
    write_dataset(cal_data, out / "calibration_data.h5")
    write_dataset(test_data, out / "test_data.h5")
    step("simulate")

    say(f"calibrating the dipole model and the rig fixtures on {cal_data.n_samples} rows "
        "(mode XYZ) from a start moved off the truth, then a concentric model ...")
    truth = truth_calibration(preset)
    write_calibration(truth, out / "truth_calibration.json")
    mode = get_mode("XYZ")
    # every fitted parameter moved: coil positions 1 mm, moments 1 %, fixtures 1 mm / 0.5 deg
    start = perturb_calibration(truth, np.random.default_rng(o.seed), mode=mode, pos=1e-3,
                                rel=1e-2, fix_t=1e-3, fix_r=np.deg2rad(0.5)
                                ).replace(mode="demo-start")
    cal = fit(cal_data, start, mode, warn=False).calibration
    concentric = fit(cal_data, cal, "concentric", warn=False).calibration
    write_calibration(concentric, out / "concentric_calibration.json")
    step("calibrate")

    say("fitting the DLT output correction on the home-fixture calibration rows (what is left "
        "of the pose error after calibration) ...")
    corr = fit_output_correction(cal_data.select(cal_data.mask(
        pattern="md", source_fixture=preset.source_fixtures[0])), cal)
    if corr.matrix is not None:
        cal = cal.replace(linear_correction=corr.matrix)
    write_calibration(cal, out / "calibration.json")
    step("output correction")

    say(f"solving and scoring the {test_data.n_samples} test rows with every calibration "
        "against the rig's known poses ...")
    result = characterize_calibration(test_data, cal, concentric=concentric)
    rows = truth_comparison_rows(test_data, truth, start, concentric, result)
    step("solve, score and figures")

    say(f"writing report {out / 'report.html'} ...")
    rep = characterization_document(result, parameter_rows(cal, truth=truth),
                                    title=f"openemt demo — simulated '{preset.name}' tracker",
                                    glossary=False)
    simulation_section(
        rep, description=preset.description,
        setup=(f"Calibration data: {cal_data.n_samples} rows (md pattern, "
               f"{len(cal_data.files)} fixture combinations); test data: "
               f"{test_data.n_samples} rows (ld pattern, home source fixture, three sensor "
               f"fixtures). Measurement SNR {o.snr_db:g} dB, stage error "
               f"{o.stage_error_um:g} um 3-D RMS, seed {o.seed}. Ground truth couplings "
               "come from finite-size coil models; the calibration fits the dipole model, "
               "starting from the truth moved by random normal amounts (standard deviations "
               "1 mm / 1 % / 0.5 deg) in every fitted parameter. The parameter table above "
               "has the truth beside every fitted value."),
        rows=rows)
    glossary_section(rep)
    rep.write(out / "report.html")
    step("write report")
    return DemoResult(
        preset=preset.name, output_dir=str(out), report=str(out / "report.html"),
        n_calibration=cal_data.n_samples, n_test=test_data.n_samples, snr_db=o.snr_db,
        stage_error_um=o.stage_error_um, seed=o.seed,
        rms_residue=cal.stats.get("rms_residue"), rows=rows, n_figures=rep.n_figures,
        seconds={**seconds, "total": round(time.perf_counter() - t_all, 3)})
