"""Pose refinement for coupling models beyond the compiled dipole solver (e.g. octupoles).

The compiled LM solves the dipole part; :func:`refine_poses` then takes a few batched
Gauss-Newton steps on the full model from there (the two solutions differ by a small amount).
"""

from __future__ import annotations

import numpy as np

from ._validity import MAX_RELATIVE_RESIDUAL, check_validity_options, rejudge, relative_residuals

__all__ = ["refine_poses", "refine_result"]


def refine_poses(model, couplings, pose_vectors, *, iterations: int = 10,
                 damping: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Refine pose vectors ``(N, 6)`` for any coupling model (:class:`openemt.field.CouplingModel`,
    e.g. an :class:`~openemt.field.OctupoleModel`) by batched Gauss-Newton.

    Starts from (for example) the dipole-model solution, which differs from the octupole-model
    solution by a small amount, and returns the refined pose vectors and the ILEMT residual
    ``sum(residual^2) / ||C||_2`` (N,). ``couplings`` are signed real or complex (the target is
    ``sign(Re z)|z|``, normalised by the complex spectral norm).
    """
    from ..geometry import pose_from_vector, vector_from_pose
    from ..io import signed_real

    C = np.asarray(couplings)
    norm = np.linalg.norm(C, ord=2, axis=(1, 2))
    Cd = signed_real(C)
    v = np.array(pose_vectors, dtype=np.float64)
    n = v.shape[0]
    lam = damping
    for _ in range(iterations):
        P = pose_from_vector(v)
        jac = model.jacobians(P, params=False)
        r = (Cd - jac.C).reshape(n, -1)
        J = jac.pose_vector(v[:, 3:]).reshape(n, -1, 6)
        JtJ = np.einsum("kma,kmb->kab", J, J)
        scale = np.sqrt(np.einsum("kaa->ka", JtJ)) + 1e-300
        JtJ = JtJ / scale[:, :, None] / scale[:, None, :] + lam * np.eye(6)
        step = np.linalg.solve(JtJ, (np.einsum("kma,km->ka", J, r) / scale)[..., None])[..., 0]
        step /= scale
        v = v + step
        # keep the rotation vector canonical (angle in [0, pi])
        v = vector_from_pose(pose_from_vector(v))
        if np.max(np.abs(step)) < 1e-10:   # m and rad: far below any measurable change
            break
    P = pose_from_vector(v)
    res = np.sum((Cd - model.coupling(P)) ** 2, axis=(1, 2)) / norm
    return v, res


def refine_result(result, model, couplings, *, max_relative_residual=MAX_RELATIVE_RESIDUAL):
    """A :class:`SolveResult` refined for ``model`` (:func:`refine_poses` on every sample with a
    finite pose): poses and residuals replaced, and CONVERGED / NOT_CONVERGED judged again by
    the relative residual under ``model`` (docs/solve.md#validity-rule); iterations kept."""
    from ..geometry import pose_from_vector
    from ..io import signed_real

    max_rel, _ = check_validity_options(max_relative_residual, None)
    ok = np.all(np.isfinite(result.pose_vectors), axis=1)
    vecs = result.pose_vectors.copy()
    poses = result.poses.copy()
    residual = result.residual.copy()
    rho = np.full(len(result), np.nan)
    if ok.any():
        C = np.asarray(couplings)[ok]
        vecs[ok], residual[ok] = refine_poses(model, C, result.pose_vectors[ok])
        poses[ok] = pose_from_vector(vecs[ok])
        rho[ok] = relative_residuals(model.coupling(poses[ok]), signed_real(C))
    status = rejudge(result.status, np.where(ok, rho, np.inf), max_rel)
    return result.replace(poses=poses, pose_vectors=vecs, residual=residual, status=status,
                          relative_residual=rho)
