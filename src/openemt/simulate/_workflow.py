"""The ``openemt simulate`` workflow: options in, the simulated files written, a result out."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import ClassVar

import numpy as np

from .._errors import InputError
from .._options import option
from .._result import Result
from ._apparatus import STAGE_SIGMA
from ._patterns import PATTERNS
from ._presets import PRESETS

__all__ = ["SimulateOptions", "SimulateResult", "parse_distortion", "write_simulation"]


@dataclasses.dataclass(frozen=True)
class SimulateOptions:
    """What ``openemt simulate`` writes (field metadata: the command-line help)."""

    output: Path = option(None, "output dataset (.h5), or export (.tsv) with --format ndi",
                          flag=("-o", "--output"), required=True)
    preset: str = option("concentric", "simulated tracker (default: concentric)", choices=PRESETS)
    board: str | None = option(None, "--preset anser: board geometry file (.toml/.json) of the "
                               "source coils (default: the built-in anser board; docs/planar.md)",
                               metavar="BOARD")
    pattern: str | None = option(None, f"stage pattern(s), comma-separated, from "
                                 f"{', '.join(PATTERNS)} (default: md; grid for anser)")
    source_fixtures: str = option("all", "'all' or comma-separated source-fixture codes (e.g. "
                                  "YoutZup,XoutZup)")
    sensor_fixtures: str = option("all", "'all' or comma-separated sensor-fixture codes (e.g. "
                                  "YoutZup,ZinYup)")
    combinations: str = option("paper", "paper: every source fixture with the home sensor "
                               "fixture plus the home source fixture with every sensor fixture; "
                               "cross: all pairs", choices=("paper", "cross"))
    snr_db: float | None = option(None, "noise by SNR (dB): per-sample sigma = rms|C| / "
                                  "10^(snr/20)")
    noise_abs: float | None = option(None, "noise with a fixed sigma (coupling units)")
    stage_sigma: float = option(STAGE_SIGMA, f"stage position error sigma per axis, m (default "
                                f"{STAGE_SIGMA:g}: 0.107 mm 3-D RMS)")
    drift: str | None = option(None, "relative source gain drift over the run: one value or one "
                               "per source coil, comma-separated (e.g. 3e-4)")
    distortion: tuple[str, ...] | None = option(
        None, "field-distorting object 'KIND,X,Y,Z,RADIUS[,conductivity=S][,mu_r=M]' with KIND "
        "conductive or ferromagnetic, centre X,Y,Z (m, bench frame) and sphere RADIUS (m); "
        "repeatable", metavar="SPEC", action="append")
    metal: str | None = option(None, "metal scene: a name (clean, aluminium_sheet, steel_plate, "
                               "moving_ring) or a scene file (.toml) in the bench frame "
                               "(docs/simulator.md#metal-scenes); couplings become complex",
                               metavar="SCENE")
    bands: str | None = option(None, "carrier bands, one per ';', each one carrier per source "
                               "coil in Hz (e.g. '274,334,370;7500,10500,13500'): couplings "
                               "of every band in the dataset (band 0 is `couplings`; "
                               "docs/simulator.md#carrier-bands)", metavar="BANDS")
    clip_z: bool = option(True, "log Z = -50 mm as commanded instead of the stage limit -46.2 mm")
    reference: str | None = option(None, "simulate a reference-pose collection instead: the sensor "
                                   "on a robot flange or optical marker (unknown X, Y), couplings "
                                   "at --n-poses random poses in the tracker's volume "
                                   "(docs/reference-calibration.md)", choices=("robot", "optical"))
    n_poses: int = option(300, "reference collection: number of poses (default 300)")
    reference_noise_mm: float | None = option(None, "reference collection: pose noise of the "
                                              "reference, 3-D RMS in mm (default robot 0.05, "
                                              "optical 0.25)", metavar="MM")
    reference_noise_deg: float | None = option(None, "reference collection: rotation noise of the "
                                               "reference, RMS angle in degrees (default robot "
                                               "0.02, optical 0.1)", metavar="DEG")
    format: str = option("h5", "h5: an openemt dataset (default); ndi (with --reference "
                         "optical): the NDI Toolbox TSV export of one session, an EM sensor's "
                         "poses (port 10, a smooth field distortion of about 3 mm) beside the "
                         "optical marker fixed to it (port 1), --n-poses rows "
                         "(docs/alignment.md)", choices=("h5", "ndi"))
    seed: int = option(0, "random seed (default 0)")
    truth_calibration: Path | None = option(None, "also write the preset's true "
                                            "dipole-equivalent calibration (JSON)",
                                            metavar="CAL.json")


@dataclasses.dataclass(frozen=True)
class SimulateResult(Result):
    """What :func:`write_simulation` wrote: the files, their sizes and the simulated truth."""

    path: str
    n_samples: int
    seed: int
    format: str = "h5"
    truth_calibration: str | None = None
    n_source: int = 0
    n_sensor: int = 0
    complex: bool = False
    preset: str = ""
    patterns: list = ()
    files: list = ()
    errors: dict | None = None
    reference: dict | None = None
    tools: list = ()
    truth: dict | None = None
    _ndi: ClassVar = ("path", "format", "n_samples", "tools", "seed", "truth")
    _h5: ClassVar = ("path", "truth_calibration", "n_samples", "n_source", "n_sensor",
                     "complex", "preset", "patterns", "files", "seed", "errors")

    def _items(self) -> dict:
        keys = self._ndi if self.format == "ndi" else self._h5 + (
            ("reference", "truth") if self.reference is not None else ())
        return {k: getattr(self, k) for k in keys}

    def lines(self) -> list[str]:
        """The human-readable summary."""
        if self.format == "ndi":
            return [f"simulated an NDI session of {self.n_samples} rows (EM sensor on port 10, "
                    f"optical marker on port 1) -> {self.path}"]
        out = [f"simulated {self.n_samples} samples ({self.n_source} x {self.n_sensor} "
               f"couplings) of preset {self.preset}: {len(self.files)} blocks -> {self.path}"]
        if self.truth_calibration is not None:
            out.append(f"truth calibration -> {self.truth_calibration}")
        return out


def _floats(text: str, name: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise InputError(f"expected {name} as comma-separated numbers, got {text!r}") from None


def parse_distortion(spec: str) -> dict:
    """``'conductive,0.1,0.25,0,0.03[,conductivity=3.5e7][,mu_r=1000]'`` -> Distortion fields."""
    parts = [s.strip() for s in spec.split(",")]
    positional = [s for s in parts if "=" not in s]
    if len(positional) != 5:
        raise InputError(f"expected --distortion 'KIND,X,Y,Z,RADIUS[,key=value]', got {spec!r}")
    nums = _floats(",".join(positional[1:]), "--distortion X,Y,Z,RADIUS")
    out = {"kind": positional[0], "position": tuple(nums[:3]), "radius": float(nums[3])}
    for kv in (s for s in parts if "=" in s):
        k, v = (s.strip() for s in kv.split("=", 1))
        if k not in ("conductivity", "mu_r"):
            raise InputError(f"expected --distortion keys conductivity or mu_r, got {k!r}")
        out[k] = float(_floats(v, f"--distortion {k}")[0])
    return out


def parse_bands(text: str) -> list:
    """``'274,334,370;7500,10500,13500'`` -> one list of carriers (Hz) per band."""
    rows = [_floats(part, "--bands").tolist() for part in text.split(";") if part.strip()]
    if not rows or len({len(r) for r in rows}) != 1:
        raise InputError(f"expected --bands as bands separated by ';', each with one carrier "
                         f"per source coil, got {text!r}")
    return rows


def _codes(text: str):
    return "all" if text.strip() == "all" else [c.strip() for c in text.split(",") if c.strip()]


def write_simulation(o: SimulateOptions, say=None) -> SimulateResult:
    """Simulate what ``o`` describes and write it (the dataset, and the truth calibration with
    ``truth_calibration``; nothing is left behind on failure). ``say`` is unused (the
    workflows' common signature)."""
    from ..io import write_calibration, write_dataset
    from ._apparatus import simulate, truth_calibration
    from ._presets import anser_preset
    from ._reference import reference_truth_calibration, simulate_reference

    o = dataclasses.replace(o, output=Path(o.output), truth_calibration=None if
                            o.truth_calibration is None else Path(o.truth_calibration))
    drift = None
    if o.drift is not None:
        d = _floats(o.drift, "--drift")
        drift = float(d[0]) if d.size == 1 else d
    distortion = [parse_distortion(s) for s in o.distortion or []]
    from .._atomic import check_outputs

    check_outputs({"-o": o.output, "--truth-calibration": o.truth_calibration})
    if o.format == "ndi":
        return _write_ndi(o)
    if o.reference is not None:
        if o.pattern is not None or o.distortion or o.drift is not None or o.metal or o.bands:
            raise InputError("expected no --pattern, --distortion, --metal, --bands or --drift "
                             "with --reference (a reference collection draws its own poses), "
                             "got some")
        mm, deg = o.reference_noise_mm, o.reference_noise_deg
        ds = simulate_reference(o.preset, o.reference, o.n_poses,
                                noise_trans=None if mm is None else mm * 1e-3,
                                noise_rot=None if deg is None else np.deg2rad(deg),
                                snr_db=o.snr_db, noise_abs=o.noise_abs, seed=o.seed)
        cal = None if o.truth_calibration is None else reference_truth_calibration(
            o.preset, ds.meta["truth"]["X"], ds.meta["truth"]["Y"])
    else:
        if o.board is not None and o.preset != "anser":
            raise InputError(f"expected --board only with --preset anser, got --preset "
                             f"{o.preset}")
        preset = o.preset if o.board is None else anser_preset(o.board)
        ds = simulate(preset, o.pattern, source_fixtures=_codes(o.source_fixtures),
                      sensor_fixtures=_codes(o.sensor_fixtures), combinations=o.combinations,
                      snr_db=o.snr_db, noise_abs=o.noise_abs, stage_sigma=o.stage_sigma,
                      drift=drift, distortion=distortion or None, metal=o.metal,
                      bands=None if o.bands is None else parse_bands(o.bands),
                      clip_z=o.clip_z, seed=o.seed)
        cal = truth_calibration(preset) if o.truth_calibration is not None else None
    existed = o.output.exists()
    write_dataset(ds, o.output)
    if cal is not None:
        try:
            write_calibration(cal, o.truth_calibration)
        except BaseException:
            if not existed:  # no partial result: drop the dataset written just before
                o.output.unlink(missing_ok=True)
            raise
    ref = ds.meta.get("reference")
    return SimulateResult(
        path=str(o.output), n_samples=ds.n_samples, seed=o.seed,
        truth_calibration=None if cal is None else str(o.truth_calibration),
        n_source=ds.n_source, n_sensor=ds.n_sensor,
        complex=bool(np.iscomplexobj(ds.couplings)), preset=o.preset,
        patterns=ds.meta.get("patterns", [o.reference]), files=list(ds.files),
        errors=ds.meta["errors"], reference=ref,
        truth=None if ref is None else {k: ds.meta["truth"][k] for k in ("X", "Y")})


def _write_ndi(o: SimulateOptions) -> SimulateResult:
    """``format="ndi"``: one simulated NDI Toolbox session export (simulate_ndi_session)."""
    from ..io import write_ndi_tsv
    from ._hybrid import simulate_ndi_session

    given = [opt for opt, value in (("--truth-calibration", o.truth_calibration),
                                    ("--pattern", o.pattern), ("--drift", o.drift),
                                    ("--distortion", o.distortion), ("--metal", o.metal),
                                    ("--bands", o.bands),
                                    ("--snr-db", o.snr_db), ("--noise-abs", o.noise_abs),
                                    ("--reference-noise-mm", o.reference_noise_mm),
                                    ("--reference-noise-deg", o.reference_noise_deg))
             if value is not None]
    if o.reference != "optical" or given:
        got = (", ".join(given) if o.reference == "optical" else
               "no --reference" if o.reference is None else f"--reference {o.reference}")
        raise InputError(f"expected --format ndi with --reference optical, --n-poses and "
                         f"--seed only (a pose export of an EM sensor and an optical marker), "
                         f"got {got}")
    tools, truth = simulate_ndi_session(o.n_poses, seed=o.seed)
    write_ndi_tsv(o.output, tools)
    return SimulateResult(path=str(o.output), n_samples=int(o.n_poses), seed=o.seed,
                          format="ndi", tools=list(tools),
                          truth={"X": truth["X"], "Y": truth["Y"]})
