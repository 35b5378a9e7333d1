"""Pose solution: closed forms (the SVD closed form of Teixeira Silva et al. 2017, Kuipers, Kim18), a compiled batched
Levenberg-Marquardt solver for any dipole model, the 5-DOF finite-coil board solver, the
Cramer-Rao bound and a chunked runner. :func:`prepare` makes every one of them from a
calibration or a model and one options record (:class:`SolveOptions`).

See docs/solve.md for the algorithms, status codes, SNR definition and benchmarks.
"""

from .._lazy import lazy_exports

#: where each public name lives; a module is imported on first use of one of its names
_SOURCES = {
    "._sheet": ("SHEET_GOOD_RESIDUAL", "SHEET_SEARCHES", "SheetFit", "fit_sheet",
                "sheet_couplings"),
    "._bands": ("BAND_METHODS", "DEFAULT_BAND_TIME_CONSTANT_S", "LIVE_BAND_METHODS",
                "BandReader", "BandStage",
                "cole_cole_couplings", "eddy_free_couplings", "fuse_bands", "resolve_bands"),
    "._closed_form": ("solve_kim18", "solve_kuipers", "solve_svd", "spectral_norms"),
    "._crb": ("cramer_rao", "solver_covariance"),
    "._factory": ("SOLVER_FAMILIES", "prepare"),
    "._grid": ("GridData", "PlanarErrors", "planar_accuracy", "planar_errors"),
    "._hemisphere": ("hemisphere_from_positions", "hemisphere_vectors", "rig_hemispheres"),
    "._lm_solver": ("solve_lm",),
    "._lm_starts": ("closed_form_start",),
    "._options": ("SolveOptions",),
    "._output": ("POSES_SCHEMA", "read_poses"),
    "._planar": ("pose_from_axis", "solve_planar"),
    "._refine": ("refine_poses",),
    "._result": ("SolveResult", "Status", "status_count_names"),
    "._runner": ("SOLVERS", "apply_position_correction", "solve", "solve_chunks"),
    "._series": ("solve_series",),
    "._tofile": ("solve_to_file",),
    "._workflow": ("RowFixtures", "SolveFileOptions", "SolveFileResult", "failure_reasons",
                   "solve_file"),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
