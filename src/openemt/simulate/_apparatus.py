"""The simulated calibration apparatus: fixtures, stage, kinematics and the ``simulate`` entry.

A simulated run visits, for each manual fixture combination (source fixture outer, sensor
fixture inner) and each stage pattern (innermost), the pattern's stage poses, like the ILEMT
data collection (docs/paper-procedure.md#parameter-groups). The true pose of every row is the kinematic chain
``P = F_so . so_J . F_st . st_J . F_se`` (MacLachlan et al. 2025, eq. 6) evaluated at the stage pose actually
reached (commanded + stage error); the dataset's ``stage`` keeps the commanded values, like a
real log.
"""

from __future__ import annotations

import numpy as np

from .. import __version__
from .._errors import InputError, check_nonnegative
from ..geometry import ground_truth_poses, pose_from_rt, pose_from_vector, source_fixture_rotation
from ..io import Calibration, Dataset
from ._errors import (
    Distortion,
    add_noise,
    distortion_coupling,
    drift_factors,
    noise_sigma,
    polarizability,
)
from ._metal import load_scene
from ._patterns import STAGE_Z_LIMIT, stage_pattern
from ._presets import Preset, get_preset

__all__ = ["STAGE_SIGMA", "fixture_combinations", "scene_model", "simulate",
           "truth_calibration"]

#: Default stage position error sigma per axis (m): MacLachlan et al. 2025 (§VIII-C) quote a stage uncertainty of
#: 0.107 mm after compensation and adds it to the RMS of the 3-D error magnitude (eq. 10), so it
#: is a 3-D RMS; per axis that is 107 um / sqrt(3) = 61.8 um.
STAGE_SIGMA = 107e-6 / np.sqrt(3.0)


def _codes(value, supported: tuple[str, ...], name: str) -> list[str]:
    if value is None or (isinstance(value, str) and value == "all"):
        return list(supported)
    codes = [value] if isinstance(value, str) else list(value)
    if not codes:
        raise InputError(f"expected at least one {name} code or 'all', got none")
    for c in codes:
        if c not in supported:
            raise InputError(f"expected {name} codes in {list(supported)} or 'all', got {c!r}")
    if len(set(codes)) != len(codes):
        raise InputError(f"expected distinct {name} codes, got {codes}")
    return codes


def fixture_combinations(preset, source_fixtures="all", sensor_fixtures="all", *,
                         combinations: str = "paper") -> list[tuple[str, str]]:
    """The (source fixture, sensor fixture) pairs a run visits, source outer, sensor inner.

    ``combinations="paper"``: when both lists contain the home fixture (``YoutZup``, the first of
    the preset's supported codes), every source fixture with the home sensor fixture plus the
    home source fixture with every sensor fixture, as collected for MacLachlan et al. 2025, §VIII-D (6 combinations for
    "all" x "all" with the ILEMT rig). Otherwise (one of the lists lacks its home fixture) the
    full cross product of the two lists. ``combinations="cross"``: always the cross product
    (12 for the ILEMT rig).
    """
    p = get_preset(preset)
    so = _codes(source_fixtures, p.source_fixtures, "source fixture")
    se = _codes(sensor_fixtures, p.sensor_fixtures, "sensor fixture")
    if combinations not in ("paper", "cross"):
        raise InputError(f"expected combinations 'paper' or 'cross', got {combinations!r}")
    home_so, home_se = p.source_fixtures[0], p.sensor_fixtures[0]
    paper = combinations == "paper" and home_so in so and home_se in se
    return [(s, e) for s in so for e in se if not paper or s == home_so or e == home_se]


def _patterns(pattern, preset: Preset) -> list[str]:
    if pattern is None:
        return [preset.default_pattern]
    names = [p.strip() for p in pattern.split(",")] if isinstance(pattern, str) else list(pattern)
    if not names or any(not isinstance(n, str) or not n for n in names):
        raise InputError(f"expected one or more stage pattern names, got {pattern!r}")
    if len(set(names)) != len(names):
        raise InputError(f"expected distinct stage pattern names, got {names}")
    return names


def _distortions(distortion) -> list[Distortion]:
    if distortion is None:
        return []
    if isinstance(distortion, (Distortion, dict)):
        distortion = [distortion]
    return [Distortion.from_any(d) for d in distortion]



def simulate(preset, pattern=None, *, source_fixtures="all", sensor_fixtures="all",
             combinations: str = "paper", snr_db=None, noise_abs=None,
             stage_sigma=STAGE_SIGMA, drift=None, distortion=None, metal=None, bands=None,
             clip_z: bool = True, seed=0) -> Dataset:
    """Simulate an ILEMT-style calibration/test data collection with known ground truth.

    Parameters
    ----------
    preset : str or Preset
        ``concentric``, ``dipole-approx`` or ``anser`` (see :func:`get_preset`).
    pattern : str or sequence of str, optional
        Stage pattern name(s) (:func:`stage_pattern`); a string may hold several names separated
        by commas. Default: the preset's default pattern (``md``; ``grid`` for anser).
    source_fixtures, sensor_fixtures : "all", str or sequence of str
        Manual fixture codes; combined as described in :func:`fixture_combinations`.
    combinations : {"paper", "cross"}
        How the two fixture lists combine.
    snr_db : float, optional
        Measurement noise by signal-to-noise ratio: white Gaussian noise on every coupling entry
        with per-sample ``sigma = rms(|C_true|) / 10**(snr_db/20)`` (see :func:`noise_sigma`).
    noise_abs : float, optional
        Measurement noise with a fixed sigma (coupling units). Not together with ``snr_db``.
    stage_sigma : float, default 107e-6 / sqrt(3)
        Standard deviation (m) of the stage position error on each of x, y, z (the default gives
        the paper's 0.107 mm 3-D RMS stage uncertainty); the true poses use
        commanded + error, ``stage`` keeps the commanded values. 0 disables it.
    drift : float or array (n_source,), optional
        Relative source gain change over the run (linear in acquisition order), e.g. 3e-4.
    distortion : Distortion, dict or list of them, optional
        Objects that distort the field (induced dipoles, see :class:`Distortion`). Couplings are
        complex when a conductive object is present, else real.
    metal : MetalScene, str, dict, optional
        A metal scene (:class:`openemt.simulate.MetalScene`, a scene name such as
        ``"aluminium_sheet"``, a TOML scene file or a table) in the bench frame, the
        source-fixture base frame (docs/simulator.md#metal-scenes); a named scene is placed
        about the box of the simulated sensor positions in that frame. Row ``k`` is at time
        ``k * sample_period_s`` for moving objects. Couplings are complex with a scene.
    bands : array (n_bands, n_source), optional
        Carrier bands: every source coil driven at one frequency per band (Hz), e.g. ILEMT's
        ``[[274, 334, 370], [7500, 10500, 13500]]``. ``couplings`` are band 0's and
        ``extra["couplings_bands"]`` (N, n_bands, n_source, n_sensor) holds all of them (each
        with its own metal response and noise; ``meta["band_frequencies_hz"]`` their
        carriers); default: the preset's frequencies, one band.
    clip_z : bool, default True
        Log commanded Z below -46.2 mm as -46.2 mm, like the real stage (:func:`stage_pattern`).
    seed : int or None
        Seed of ``np.random.default_rng``; stage errors and noise use separate child streams, so
        switching noise on or off does not change the stage errors.

    Returns
    -------
    Dataset
        ``couplings`` (N, n_source, n_sensor); ``stage`` = commanded stage (m, rad), also in
        ``stage_logged``; ``poses`` = true poses; fixture codes; ``pattern``; ``files`` naming each
        simulated block like the ILEMT files (``soYoutZup_seZinYup_md``); ``extra`` with
        ``stage_true`` (N, 6) and ``noise_sigma`` (N,); ``meta`` with the preset, the truth, the
        seed and every error setting, and provenance.

    Examples
    --------
    The paper's calibration data (md pattern, six fixture combinations) of the simulated
    dipole-approximating source, then its true calibration refitted from a perturbed start:

    >>> import numpy as np
    >>> import openemt
    >>> from openemt.calibrate import perturb_calibration
    >>> from openemt.simulate import simulate, truth_calibration
    >>> data = simulate("dipole-approx", "md", snr_db=80.0, seed=1)
    >>> len(data), len(data.files), data.poses.shape
    (852, 6, (852, 4, 4))
    >>> truth = truth_calibration("dipole-approx")
    >>> start = perturb_calibration(truth, np.random.default_rng(0), mode="XYZ")
    >>> fitted = openemt.fit_calibration(data, start, mode="XYZ", warn=False).calibration
    >>> bool(np.abs(fitted.model.L_so - truth.model.L_so).max() < 1e-3)
    True
    """
    p = get_preset(preset)
    names = _patterns(pattern, p)
    stages = {n: stage_pattern(n, clip_z=clip_z) for n in names}
    combos = fixture_combinations(p, source_fixtures, sensor_fixtures, combinations=combinations)
    stage_sigma = check_nonnegative(stage_sigma, "stage_sigma")
    if snr_db is not None and noise_abs is not None:
        raise InputError(f"expected at most one of snr_db and noise_abs, got snr_db={snr_db!r} "
                         f"and noise_abs={noise_abs!r}")
    if noise_abs is not None:
        check_nonnegative(noise_abs, "noise_abs")
    objects = _distortions(distortion)

    blocks, files, so_codes, se_codes, pats, file_index = [], [], [], [], [], []
    for s, e in combos:
        for n in names:
            rows = stages[n]
            file_index.append(np.full(len(rows), len(files)))
            files.append(f"so{s}_se{e}_{n}")
            blocks.append(rows)
            so_codes += [s] * len(rows)
            se_codes += [e] * len(rows)
            pats += [n] * len(rows)
    stage = np.vstack(blocks)
    n_rows = stage.shape[0]

    stage_rng, noise_rng = np.random.default_rng(seed).spawn(2)
    stage_true = stage.copy()
    if stage_sigma > 0:
        stage_true[:, :3] += stage_sigma * stage_rng.standard_normal((n_rows, 3))
    poses = ground_truth_poses(p.source_fixture, p.stage_fixture, p.sensor_fixture, so_codes,
                               stage_true, se_codes)

    C0 = p.model.coupling(poses)
    band_f = _bands(bands, p)
    if objects or metal is not None:
        F_so = pose_from_vector(p.source_fixture)
        so_J = {c: source_fixture_rotation(c) for c in set(so_codes)}
        # bench (source-fixture base) frame -> source frame: F_so . so_J
        M = np.stack([so_J[c] for c in so_codes])                   # (N, 3, 3)
        A = np.einsum("ab,kbc->kac", F_so[:3, :3], M)                # rotation of F_so so_J
        frame = pose_from_rt(A, F_so[:3, 3])
    scene = None
    if metal is not None:           # a named scene is placed about the simulated volume
        bench = np.einsum("kba,kb->ka", A, poses[:, :3, 3] - F_so[:3, 3])
        scene = load_scene(metal, volume=(bench.min(axis=0), bench.max(axis=0)))
    Cb = []
    for freqs in band_f:                          # each carrier band sees its own response
        C = C0
        if scene is not None:
            C = C + scene.induced_couplings(scene_model(p), poses, freqs,
                                            t=scene.times(n_rows), frame=frame)
        for d in objects:
            q = frame[:, :3, 3] + np.einsum("kab,b->ka", A, np.asarray(d.position))
            C = C + distortion_coupling(p.dipole, poses, q, polarizability(d, freqs), d.radius)
        if scene is None and not any(d.kind == "conductive" for d in objects):
            C = np.real(C).copy()
        Cb.append(C)
    sigma = np.zeros(n_rows)
    for b, C in enumerate(Cb):
        if drift is not None:
            C = C * drift_factors(drift, n_rows, p.n_source)[:, :, None]
        if snr_db is not None or noise_abs is not None:
            sigma = noise_sigma(C, snr_db=snr_db, noise_abs=noise_abs) if b == 0 else sigma
            C = add_noise(C, noise_sigma(C, snr_db=snr_db, noise_abs=noise_abs), noise_rng)
        Cb[b] = C
    C = Cb[0]
    extra = {"stage_true": stage_true, "noise_sigma": sigma}
    if bands is not None:
        extra["couplings_bands"] = np.stack(Cb, axis=1)

    meta = {
        "generator": "openemt.simulate",
        "preset": p.name,
        "description": p.description,
        "source": p.source,
        "sensor": p.sensor,
        "seed": seed if seed is None else int(seed),
        "patterns": names,
        "fixture_combinations": [list(c) for c in combos],
        "combinations": combinations,
        "clip_z": bool(clip_z),
        "stage_z_limit_m": STAGE_Z_LIMIT,
        "errors": {
            "snr_db": None if snr_db is None else float(snr_db),
            "noise_abs": None if noise_abs is None else float(noise_abs),
            "noise_definition": "per-sample sigma = rms(|C_true|) / 10**(snr_db/20), white "
                                "Gaussian on each entry (and on the quadrature part if complex)",
            "stage_sigma_m": stage_sigma,
            "drift": None if drift is None else np.atleast_1d(drift).astype(float).tolist(),
            "distortion": [d.to_dict() for d in objects],
            "metal": None if scene is None else scene.to_dict(),
        },
        "truth": {
            "finite_coils": bool(p.finite),
            "source_fixture": p.source_fixture.tolist(),
            "stage_fixture": p.stage_fixture.tolist(),
            "sensor_fixture": p.sensor_fixture.tolist(),
            "frequencies_hz": p.frequencies.tolist(),
        },
        "units": {"stage": "m, rad", "couplings": "dimensionless (gain 1/250 convention)"},
        **({} if bands is None else {"band_frequencies_hz": band_f.tolist()}),
        "provenance": {"openemt_version": __version__, "simulated": True},
    }
    return Dataset(couplings=C, stage=stage, source_fixture=np.array(so_codes),
                   sensor_fixture=np.array(se_codes), pattern=np.array(pats),
                   file_index=np.concatenate(file_index), files=tuple(files),
                   stage_logged=stage.copy(), poses=poses,
                   extra=extra, meta=meta)


def _bands(bands, p: Preset) -> np.ndarray:
    if bands is None:
        return p.frequencies[None, :]
    f = np.asarray(bands, dtype=np.float64)
    if f.ndim == 1:
        f = f[None, :]
    if f.ndim != 2 or f.shape[1] != p.n_source or not np.all(np.isfinite(f)) or np.any(f <= 0):
        raise InputError(f"expected carrier bands of shape (n_bands, {p.n_source}) with "
                         f"positive frequencies, got {np.asarray(bands).tolist()}")
    return f


def scene_model(preset):
    """The coil geometry a metal scene sees for ``preset``: its ``metal_model`` (the Anser
    board's traces), its board model where the truth is one, else its dipole-equivalent
    model (the rig presets' coils are small against their distances to the metal)."""
    from ..board import BoardModel

    p = get_preset(preset)
    if p.metal_model is not None:
        return p.metal_model
    return p.model if isinstance(p.model, BoardModel) else p.dipole


def truth_calibration(preset) -> Calibration:
    """The preset's true model (its dipole equivalent for finite coils without a parameter
    vector) with the true fixtures, as a ``Calibration``.

    Mode ``"truth"``. Solving simulated data with it gives the error that is due to the dipole
    approximation of the finite coils alone (no calibration error).

    Examples
    --------
    >>> from openemt.simulate import truth_calibration
    >>> truth = truth_calibration("concentric")
    >>> truth.mode, truth.model.n_source, truth.model.n_sensor
    ('truth', 3, 3)
    """
    from ..field import CouplingModel

    p = get_preset(preset)
    # a preset whose truth is itself a calibratable model (the anser-6dof board) has that
    # model as its truth; a finite-coil truth without parameters has its dipole equivalent
    return Calibration(
        model=p.model if isinstance(p.model, CouplingModel) else p.dipole,
        source_fixture=p.source_fixture.copy(),
        stage_fixture=p.stage_fixture.copy(), sensor_fixture=p.sensor_fixture.copy(),
        mode="truth",
        provenance={"openemt_version": __version__, "preset": p.name,
                    "generator": "openemt.simulate.truth_calibration"},
        extra={"preset": p.name, "finite_coils": bool(p.finite)})
