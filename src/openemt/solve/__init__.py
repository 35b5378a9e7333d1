"""Pose solution: closed forms (the SVD closed form of Teixeira Silva et al. 2017, Kuipers, Kim18), a compiled batched
Levenberg-Marquardt solver for any dipole model, the 5-DOF finite-coil board solver, the
Cramer-Rao bound and a chunked runner. :func:`prepare` makes every one of them from a
calibration or a model and one options record (:class:`SolveOptions`).

See docs/solve.md for the algorithms, status codes, SNR definition and benchmarks.
"""

from ._bands import (
    BAND_METHODS,
    DEFAULT_BAND_TIME_CONSTANT_S,
    BandReader,
    BandStage,
    cole_cole_couplings,
    eddy_free_couplings,
    fuse_bands,
    resolve_bands,
)
from ._closed_form import solve_kim18, solve_kuipers, solve_svd, spectral_norms
from ._crb import cramer_rao, solver_covariance
from ._factory import SOLVER_FAMILIES, prepare
from ._grid import GridData, PlanarErrors, planar_accuracy, planar_errors
from ._hemisphere import hemisphere_from_positions, hemisphere_vectors, rig_hemispheres
from ._lm_solver import solve_lm
from ._lm_starts import closed_form_start
from ._options import SolveOptions
from ._output import POSES_SCHEMA, PoseWriter, read_poses
from ._planar import pose_from_axis, solve_planar
from ._refine import refine_poses
from ._result import SolveResult, Status, status_count_names
from ._runner import SOLVERS, apply_position_correction, solve, solve_chunks
from ._series import solve_series
from ._tofile import solve_to_file
from ._workflow import (
    RowFixtures,
    SolveFileOptions,
    SolveFileResult,
    failure_reasons,
    solve_file,
)

__all__ = [
    "BAND_METHODS",
    "BandReader",
    "BandStage",
    "DEFAULT_BAND_TIME_CONSTANT_S",
    "GridData",
    "POSES_SCHEMA",
    "PlanarErrors",
    "SOLVERS",
    "SOLVER_FAMILIES",
    "RowFixtures",
    "SolveFileOptions",
    "SolveFileResult",
    "SolveOptions",
    "PoseWriter",
    "SolveResult",
    "Status",
    "apply_position_correction",
    "closed_form_start",
    "cole_cole_couplings",
    "cramer_rao",
    "eddy_free_couplings",
    "failure_reasons",
    "fuse_bands",
    "hemisphere_from_positions",
    "hemisphere_vectors",
    "planar_accuracy",
    "planar_errors",
    "prepare",
    "read_poses",
    "resolve_bands",
    "pose_from_axis",
    "refine_poses",
    "rig_hemispheres",
    "solve",
    "solve_chunks",
    "solve_file",
    "solve_kim18",
    "solve_kuipers",
    "solve_lm",
    "solve_planar",
    "solve_series",
    "solve_svd",
    "solve_to_file",
    "solver_covariance",
    "status_count_names",
    "spectral_norms",
]
