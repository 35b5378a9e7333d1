"""Pose solution: closed forms (seed 004 SVD, Kuipers, Kim18), a compiled batched
Levenberg-Marquardt solver for any dipole model, the Cramer-Rao bound and a chunked runner."""

from ._closed_form import solve_kim18, solve_kuipers, solve_svd, spectral_norms
from ._crb import cramer_rao
from ._hemisphere import hemisphere_from_positions, hemisphere_vectors
from ._lm_solver import solve_lm
from ._result import SolveResult, Status

__all__ = [
    "SolveResult",
    "Status",
    "cramer_rao",
    "hemisphere_from_positions",
    "hemisphere_vectors",
    "solve_kim18",
    "solve_kuipers",
    "solve_lm",
    "solve_svd",
    "spectral_norms",
]
