"""An improved calibration: a better model of the rig's kinematics and of the coils.

The paper's model (MacLachlan et al. 2025, eq. 6) takes the rig's known motions as exact. They are not: the
manual 90-degree sensor-fixture rotations are set by hand, and the stage's Rz axis has its own
angle errors and tilt. The dipole coils then absorb those errors. This module adds, all fitted on
the calibration (md) rows only:

* ``sensor_code_fix`` -- a small pose correction ``delta_c`` (6 numbers) per non-home sensor
  fixture code, inserted after the nominal fixture rotation: ``st_J = T(t) Rz(theta') S(c)
  delta_c`` (the home code's error is part of F_se);
* ``rz_poly`` -- an Rz angle error polynomial ``theta' = theta + sum_p a_p theta^p``;
* ``rz_tilt`` -- a tilt ``w = (wx, wy)`` of the Rz axis relative to the stage's XYZ axes:
  ``Rz(theta') -> E Rz(theta') E^T``, ``E = exp([wx, wy, 0]x)``;
* ``source_code_fix`` -- as ``sensor_code_fix`` for the source fixture (only with several
  source fixtures in the data);
* ``k_so`` / ``k_se`` -- an axial octupole per coil (finite coil size, :mod:`openemt.field._octupole`);
* ``rz_motion`` -- the Rz axis's error motions (runout, wobble, angle error) as harmonics of
  the angle; ``gain_nonlinear`` -- a signal-level dependent gain per sensor channel;
  ``coupling_offset`` -- a pose-independent coupling added to every reading (crosstalk)
  (:mod:`openemt.calibrate._rig`).

A global stage scale is deliberately not offered: a uniform scale trades exactly against the coil
gains. The improved rig model also defines the ground truth of the test rows, since it is a
calibration of the same rig (the test data never enter any fit or choice).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError
from .._result import Result
from ..field import (
    EnvironmentModel,
    EnvironmentTerms,
    ModelJacobians,
    OctupoleModel,
)
from ..geometry import (
    SENSOR_FIXTURES,
    SOURCE_FIXTURES,
    adjoint,
    left_jacobian_so3,
    pose_from_rt,
    pose_from_vector,
    rotation_x,
    rotation_y,
    rotation_z,
    sensor_fixture_rotation,
)
from ..io import signed_real
from ._layout import ParameterLayout
from ._lsq import fit_free_parameters
from ._objective import build_problem, fixture_twist_map
from ._rig import (
    error_motion_twists,
    gain_linearise,
    gain_linearise_gradient,
)

__all__ = ["STAGE_LINEAR_BASIS", "ImprovedFit", "ImprovedProblem", "RigModel", "RigOptions",
           "carry_parameters", "fit_improved"]


#: Start of the induced dipole's position: this far beyond the centroid of the fitted rows,
#: seen from the source (m).
INDUCED_START_OFFSET_M = 0.15


@dataclass(frozen=True)
class RigOptions:
    """Which extra rig and coil parameters an improved calibration fits (see module doc)."""

    sensor_code_fix: bool = True
    source_code_fix: bool = False
    rz_poly: int = 1
    rz_tilt: bool = True
    octupole_source: bool = True
    octupole_sensor: bool = False
    stage_linear: tuple = ()
    rz_motion: int = 0
    gain_nonlinear: bool = False
    coupling_offset: bool = False
    induced: bool = False
    induced_start: tuple | None = None


#: Basis of the stage's linear-map errors ``t -> (I + G) t``; ``stage_linear`` picks entries
#: by name. Non-orthogonality (``xy``, ``xz``, ``yz``: symmetric shear), axis rotations
#: (``rx``, ``ry``, ``rz``: antisymmetric) and relative scales (``sx_sz``, ``sy_sz``). A uniform
#: scale is not offered (it trades against the coil gains).
STAGE_LINEAR_BASIS = {
    "xy": np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0]], dtype=float),
    "xz": np.array([[0, 0, 1], [0, 0, 0], [1, 0, 0]], dtype=float),
    "yz": np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0]], dtype=float),
    "rx": np.array([[0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=float),
    "ry": np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], dtype=float),
    "rz": np.array([[0, -1, 0], [1, 0, 0], [0, 0, 0]], dtype=float),
    "sx_sz": np.diag([1.0, 0.0, -1.0]),
    "sy_sz": np.diag([0.0, 1.0, -1.0]),
    "sz": np.diag([0.0, 0.0, 1.0]),
}


@dataclass(frozen=True, eq=False)
class RigModel:
    """Extra parameters of the improved rig and coil model (all zero = the paper's model).

    Attributes
    ----------
    sensor_codes, source_codes : tuple of str
        Fixture codes with a correction (non-home codes).
    sensor_fix, source_fix : ndarray, shape (n_codes, 6)
        Pose-vector corrections of those codes.
    rz_poly : ndarray, shape (k,)
        Rz angle-error polynomial coefficients ``a_1..a_k`` (``theta' = theta + sum a_p theta^p``).
    rz_tilt : ndarray, shape (2,)
        Rz axis tilt (rotation vector x, y components, rad).
    k_so, k_se : ndarray, shape (n_source,), (n_sensor,)
        Octupole strengths (m^2).
    rz_motion : ndarray, shape (2 order, 6)
        Rz error-motion coefficients (rows ``sin theta, 1 - cos theta, sin 2 theta, ...``;
        columns translation m, rotation rad; :func:`openemt.calibrate._rig.error_motion_basis`).
    gain_beta : ndarray, shape (n_sensor,) or None
        Gain non-linearity per sensor channel (per unit coupling).
    offset : ndarray, shape (n_source, n_sensor) or None
        Pose-independent coupling offset (crosstalk), in coupling units.
    induced : ndarray, shape (3 + 3 n_source,) or None
        Position (m, source frame) and per-carrier moments of an induced dipole
        (the induced dipoles of :class:`openemt.field.EnvironmentModel`).
    """

    sensor_codes: tuple = ()
    sensor_fix: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    source_codes: tuple = ()
    source_fix: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    rz_poly: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rz_tilt: np.ndarray = field(default_factory=lambda: np.zeros(2))
    k_so: np.ndarray | None = None
    k_se: np.ndarray | None = None
    stage_linear_names: tuple = ()
    stage_linear: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rz_motion: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    gain_beta: np.ndarray | None = None
    offset: np.ndarray | None = None
    induced: np.ndarray | None = None

    def environment(self) -> EnvironmentTerms:
        """The induced dipole, gain non-linearity and coupling offset as the environment terms
        a calibration carries (:class:`openemt.field.EnvironmentTerms`; empty without them)."""
        q, mu = np.zeros((0, 3)), np.zeros((0, 0, 3))
        if self.induced is not None:
            v = np.asarray(self.induced, dtype=np.float64)
            q, mu = v[None, :3], v[3:].reshape(1, -1, 3)
        return EnvironmentTerms(q, mu, self.gain_beta, self.offset)

    def to_dict(self) -> dict:
        """JSON-ready form (stored in ``Calibration.extra['rig']``)."""
        return {"sensor_fixture_corrections": {c: v.tolist() for c, v in
                                               zip(self.sensor_codes, self.sensor_fix)},
                "source_fixture_corrections": {c: v.tolist() for c, v in
                                               zip(self.source_codes, self.source_fix)},
                "rz_poly": np.asarray(self.rz_poly).tolist(),
                "rz_tilt": np.asarray(self.rz_tilt).tolist(),
                "octupole_k_so": None if self.k_so is None else self.k_so.tolist(),
                "octupole_k_se": None if self.k_se is None else self.k_se.tolist(),
                "stage_linear": dict(zip(self.stage_linear_names,
                                         np.asarray(self.stage_linear).tolist())),
                "rz_error_motion": np.asarray(self.rz_motion).tolist(),
                "gain_nonlinearity": None if self.gain_beta is None else
                np.asarray(self.gain_beta).tolist(),
                "coupling_offset": None if self.offset is None else
                np.asarray(self.offset).tolist(),
                "induced_dipole": None if self.induced is None else {
                    "position": np.asarray(self.induced)[:3].tolist(),
                    "moments": np.asarray(self.induced)[3:].reshape(-1, 3).tolist()}}


class ImprovedProblem:
    """Residuals and analytic Jacobian of the improved model on a set of rows.

    The parameter vector is the :class:`ParameterLayout` vector followed by the extra blocks
    named in ``self.extra`` (slices).
    """

    def __init__(self, dataset, layout: ParameterLayout, gain: float, options: RigOptions):
        self.base = build_problem(dataset, layout, gain)
        self.layout = layout
        self.options = options
        self.stage = np.asarray(dataset.stage, dtype=np.float64)
        se = np.asarray(dataset.sensor_fixture).astype(str)
        so = np.asarray(dataset.source_fixture).astype(str)
        self.sensor_codes = tuple(c for c in SENSOR_FIXTURES[1:] if c in se) + tuple(
            sorted(set(se) - set(SENSOR_FIXTURES)))
        self.source_codes = tuple(c for c in SOURCE_FIXTURES[1:] if c in so) + tuple(
            sorted(set(so) - set(SOURCE_FIXTURES)))
        if not options.sensor_code_fix:
            self.sensor_codes = ()
        if not options.source_code_fix:
            self.source_codes = ()
        self.se_rows = [se == c for c in self.sensor_codes]
        self.so_rows = [so == c for c in self.source_codes]
        n = len(se)
        S = np.zeros((n, 3, 3))
        for c in np.unique(se):
            S[se == c] = sensor_fixture_rotation(str(c))
        self.S = S
        self.soR = self.base.so_J[:, :3, :3]
        sizes = {"sensor_fix": 6 * len(self.sensor_codes), "source_fix": 6 * len(self.source_codes),
                 "rz_poly": options.rz_poly, "rz_tilt": 2 if options.rz_tilt else 0,
                 "k_so": layout.n_source if options.octupole_source else 0,
                 "k_se": layout.n_sensor if options.octupole_sensor else 0,
                 "stage_linear": len(options.stage_linear),
                 "rz_motion": 12 * int(options.rz_motion),
                 "gain": layout.n_sensor if options.gain_nonlinear else 0,
                 "offset": layout.n_source * layout.n_sensor if options.coupling_offset else 0,
                 "induced": 3 + 3 * layout.n_source if options.induced else 0}
        bad = [b for b in options.stage_linear if b not in STAGE_LINEAR_BASIS]
        if bad:
            raise InputError(f"expected stage_linear names from {sorted(STAGE_LINEAR_BASIS)}, "
                             f"got {bad}")
        self.G_basis = np.array([STAGE_LINEAR_BASIS[b] for b in options.stage_linear]
                                ).reshape(-1, 3, 3)
        self.extra, start = {}, layout.size
        for k, s in sizes.items():
            self.extra[k] = slice(start, start + s)
            start += s
        self.size = start

    # -- parameters ---------------------------------------------------------------------------
    def rig(self, x) -> RigModel:
        e = self.extra
        return RigModel(
            sensor_codes=self.sensor_codes, sensor_fix=np.reshape(x[e["sensor_fix"]], (-1, 6)),
            source_codes=self.source_codes, source_fix=np.reshape(x[e["source_fix"]], (-1, 6)),
            rz_poly=np.array(x[e["rz_poly"]]),
            rz_tilt=np.array(x[e["rz_tilt"]]) if self.options.rz_tilt else np.zeros(2),
            k_so=np.array(x[e["k_so"]]) if self.options.octupole_source else None,
            k_se=np.array(x[e["k_se"]]) if self.options.octupole_sensor else None,
            stage_linear_names=tuple(self.options.stage_linear),
            stage_linear=np.array(x[e["stage_linear"]]),
            rz_motion=np.reshape(x[e["rz_motion"]], (-1, 6)),
            gain_beta=np.array(x[e["gain"]]) if self.options.gain_nonlinear else None,
            offset=np.reshape(x[e["offset"]], (self.layout.n_source, self.layout.n_sensor))
            if self.options.coupling_offset else None,
            induced=np.array(x[e["induced"]]) if self.options.induced else None)

    def linearised(self, C, x):
        """Couplings ``C`` with the fitted gain non-linearity and coupling offset removed
        (signed real, :meth:`openemt.io.Dataset.signed_real`); unchanged without them."""
        o = self.options
        if not (o.gain_nonlinear or o.coupling_offset):
            return C
        C = signed_real(C) if np.iscomplexobj(C) else np.asarray(C, dtype=np.float64)
        if o.gain_nonlinear:
            C = gain_linearise(C, x[self.extra["gain"]])
        if o.coupling_offset:
            C = C - np.reshape(x[self.extra["offset"]], C.shape[1:])
        return C

    def model(self, x):
        dip = self.layout.model(x, self.base.gain)
        o = self.options
        base = dip
        if o.octupole_source or o.octupole_sensor:
            k_so = x[self.extra["k_so"]] if o.octupole_source else np.zeros(dip.n_source)
            k_se = x[self.extra["k_se"]] if o.octupole_sensor else np.zeros(dip.n_sensor)
            base = OctupoleModel(dip, k_so, k_se)
        if o.induced:
            v = x[self.extra["induced"]]
            return EnvironmentModel(base, EnvironmentTerms(v[None, :3], v[None, 3:].reshape(
                1, -1, 3)))
        return base

    def full_model(self, x):
        """The model that predicts the readings, as a calibration file carries it: the dipole
        (and octupole) model with the environment terms (:class:`openemt.field.
        EnvironmentModel`: induced dipole, gain non-linearity, offset), else the base."""
        base = self.model(x)
        base = base.base if isinstance(base, EnvironmentModel) else base
        terms = self.rig(x).environment()
        return base if terms.empty else EnvironmentModel(base, terms)

    # -- kinematics ---------------------------------------------------------------------------
    def _chain(self, x):
        lay = self.layout
        F_so, F_st, F_se = (pose_from_vector(f) for f in lay.fixtures(x))
        n = self.stage.shape[0]
        dso = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        for rows, v in zip(self.so_rows, np.reshape(x[self.extra["source_fix"]], (-1, 6))):
            dso[rows] = pose_from_vector(v)
        dse = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        for rows, v in zip(self.se_rows, np.reshape(x[self.extra["sensor_fix"]], (-1, 6))):
            dse[rows] = pose_from_vector(v)
        theta = self.stage[:, 5]
        a = x[self.extra["rz_poly"]]
        theta_p = theta + sum(a[p] * theta ** (p + 1) for p in range(a.size))
        w = np.zeros(3)
        if self.options.rz_tilt:
            w[:2] = x[self.extra["rz_tilt"]]
        E = pose_from_vector(np.r_[0, 0, 0, w])[:3, :3]
        Rn = E @ rotation_z(theta_p) @ E.T
        rest = rotation_y(self.stage[:, 4]) @ rotation_x(self.stage[:, 3])
        soJ = pose_from_rt(self.soR, np.zeros(3))
        A0 = F_so @ soJ                         # prefix of a source-code correction
        A = A0 @ dso                            # prefix of F_st
        G = np.einsum("p,pab->ab", x[self.extra["stage_linear"]], self.G_basis)
        t_stage = self.stage[:, :3] + self.stage[:, :3] @ G.T
        K = A @ F_st @ pose_from_rt(np.eye(3), t_stage)              # prefix of the error motion
        if self.options.rz_motion:
            Em, Mm = error_motion_twists(theta, x[self.extra["rz_motion"]])
            K2 = K @ Em                                               # prefix of the Rz rotation
        else:
            K2, Mm = K, None
        Q = K2 @ pose_from_rt(Rn @ rest @ self.S, np.zeros(3))      # prefix of a sensor-code fix
        D = Q @ dse                             # prefix of F_se
        P = D @ F_se
        return {"P": P, "A0": A0, "A": A, "K": K, "K2": K2, "Mm": Mm, "Q": Q, "D": D, "Rn": Rn,
                "E": E, "w": w, "theta": theta}

    def poses(self, x) -> np.ndarray:
        """Ground-truth poses ``(N, 4, 4)`` of the rows under the improved rig model."""
        return self._chain(x)["P"]

    def residuals(self, x) -> np.ndarray:
        C = self.model(x).coupling(self.poses(x))
        return ((self.linearised(self.base.C_meas, x) - C)
                * self.base.weight[:, None, None]).ravel()

    def residuals_and_jacobian(self, x):
        ch = self._chain(x)
        P = ch["P"]
        model = self.model(x)
        # the model interface's Jacobians: pose derivatives and those of the model's
        # parameters, the dipole's first, then (by group) the octupole strengths and the
        # induced dipole's position and moments
        jac = model.jacobians(P)
        groups = model.parameter_groups
        lay, e = self.layout, self.extra
        # the base problem's part: the dipole parameters and fixtures
        n_dip = lay.slices["model"].stop - lay.slices["model"].start
        mj = ModelJacobians(jac.C, jac.d_translation, jac.d_rotation, jac.d_params[..., :n_dip])
        dC_base, H = self.base.gradients(x[:lay.size], mj, P, ch["A"], ch["D"])
        n, ns, ne = jac.C.shape
        J = np.zeros((n, ns, ne, self.size))
        J[..., :lay.size] = dC_base
        for c, (rows, v) in enumerate(zip(self.se_rows,
                                          np.reshape(x[e["sensor_fix"]], (-1, 6)))):
            s = slice(e["sensor_fix"].start + 6 * c, e["sensor_fix"].start + 6 * c + 6)
            J[rows, :, :, s] = _transport(H[rows], adjoint(ch["Q"][rows]) @ fixture_twist_map(v))
        for c, (rows, v) in enumerate(zip(self.so_rows,
                                          np.reshape(x[e["source_fix"]], (-1, 6)))):
            s = slice(e["source_fix"].start + 6 * c, e["source_fix"].start + 6 * c + 6)
            J[rows, :, :, s] = _transport(H[rows],
                                          adjoint(ch["A0"][rows]) @ fixture_twist_map(v))
        if e["rz_poly"].stop > e["rz_poly"].start or self.options.rz_tilt:
            HK = _transport(H, adjoint(ch["K2"])[:, :, 3:])                  # rotation part
            axis = ch["E"][:, 2]
            g_axis = HK @ axis                                                # (n, ns, ne)
            for p in range(e["rz_poly"].stop - e["rz_poly"].start):
                J[..., e["rz_poly"].start + p] = g_axis * (ch["theta"] ** (p + 1))[:, None, None]
            if self.options.rz_tilt:
                Jl = left_jacobian_so3(ch["w"])[:, :2]
                M = (np.eye(3) - ch["Rn"]) @ Jl                               # (n, 3, 2)
                J[..., e["rz_tilt"]] = _transport(HK, M)
        if self.G_basis.shape[0]:
            # t -> t + G t: a translation of the stage carriage in stage-base axes
            HKt = _transport(H, adjoint(ch["K"])[:, :, :3])
            dt = np.tensordot(self.stage[:, :3], self.G_basis, axes=([1], [2]))  # (n, p, 3)
            J[..., e["stage_linear"]] = _transport(HKt, dt.transpose(0, 2, 1))
        if self.options.rz_motion:
            J[..., e["rz_motion"]] = _transport(H, adjoint(ch["K"]) @ ch["Mm"])
        for block, group in (("k_so", "k_so"), ("k_se", "k_se"), ("induced", "induced")):
            if e[block].stop > e[block].start:
                J[..., e[block]] = jac.d_params[..., groups[group]]
        w = self.base.weight[:, None, None]
        r = (self.linearised(self.base.C_meas, x) - jac.C) * w
        J *= -w[..., None]
        if self.options.gain_nonlinear:
            J[..., e["gain"]] = gain_linearise_gradient(self.base.C_meas) * w[..., None]
        if self.options.coupling_offset:
            J[..., e["offset"]] = (-np.eye(ns * ne).reshape(ns, ne, ns * ne)
                                   * w[..., None])
        return r.ravel(), J.reshape(r.size, self.size)


def _transport(H, T) -> np.ndarray:
    """``H (N, n_so, n_se, b) @ T (N, b, c)`` per row: ``(N, n_so, n_se, c)``."""
    n, ns, ne, b = H.shape
    return np.matmul(H.reshape(n, ns * ne, b), T).reshape(n, ns, ne, -1)


@dataclass(frozen=True, eq=False)
class ImprovedFit(Result):
    """The improved model fitted by :func:`fit_improved`: the ``problem`` (its rows and
    layout), the full parameter vector ``x`` (layout + extras), the ``free`` indices and the
    least-squares ``result``. ``to_dict()`` gives the sizes and the solver's status.

    Unpacking it as the 4-tuple ``(problem, x, free, result)`` it was before still works for
    one deprecation period, with a DeprecationWarning.
    """

    _not_in_dict = ("problem", "x", "free", "result")

    problem: object
    x: np.ndarray
    free: np.ndarray
    result: object

    def _items(self) -> dict:
        return {"n_params": int(np.size(self.x)), "n_free": int(np.size(self.free)),
                "status": int(getattr(self.result, "status", 0)),
                "nfev": int(getattr(self.result, "nfev", 0))}

    def __iter__(self):
        import warnings

        warnings.warn("unpacking fit_improved() as a tuple is deprecated; use its attributes "
                      "problem, x, free, result", DeprecationWarning, stacklevel=2)
        return iter((self.problem, self.x, self.free, self.result))


def carry_parameters(prob: ImprovedProblem, x, rows, options: RigOptions | None = None
                     ) -> tuple[ImprovedProblem, np.ndarray]:
    """The problem of ``rows`` (a Dataset) under ``options`` (default ``prob``'s) with the
    parameters ``x`` of ``prob`` carried over: the layout vector, and each extra block the two
    problems share with the same size (fixture-code corrections by code; codes ``prob`` did not
    see get none). Blocks ``prob`` lacks are zero."""
    options = prob.options if options is None else options
    tp = ImprovedProblem(rows, prob.layout, prob.base.gain, options)
    xt = np.zeros(tp.size)
    xt[:prob.layout.size] = x[:prob.layout.size]
    for name, sl in tp.extra.items():
        if name in ("sensor_fix", "source_fix"):
            src = prob.sensor_codes if name == "sensor_fix" else prob.source_codes
            dst = tp.sensor_codes if name == "sensor_fix" else tp.source_codes
            vals = np.reshape(x[prob.extra[name]], (-1, 6))
            out = np.zeros((len(dst), 6))
            for i, c in enumerate(dst):
                if c in src:
                    out[i] = vals[src.index(c)]
            xt[sl] = out.ravel()
        elif prob.extra[name].stop - prob.extra[name].start == sl.stop - sl.start:
            xt[sl] = x[prob.extra[name]]
    return tp, xt


def fit_improved(dataset, start, options: RigOptions = RigOptions(), *, optimize, freeze,
                 max_nfev: int = 200, tol: float = 1e-12, initial=None) -> ImprovedFit:
    """Fit the improved model to every row of ``dataset`` from the calibration ``start``:
    an :class:`ImprovedFit` (``problem``, the full parameter vector ``x`` (layout + extras),
    ``free``, ``result``).

    ``initial`` (a fit of the improved model, e.g. on more rows or with fewer terms: an
    :class:`ImprovedFit` or ``(problem, x)``) starts the fit from its parameters instead
    (:func:`carry_parameters`; ``start`` still gives the parameters it lacks): a warm start
    for fits that converge to the same solution, in fewer iterations.
    """
    layout = ParameterLayout.for_model(start.model)
    if initial is not None:
        ip, ix = (initial.problem, initial.x) if isinstance(initial, ImprovedFit) else initial
        if (ip.layout.n_source, ip.layout.n_sensor) != (layout.n_source, layout.n_sensor):
            raise InputError(f"expected an initial fit of the start's {layout.n_source} x "
                             f"{layout.n_sensor} coils, got one of {ip.layout.n_source} x "
                             f"{ip.layout.n_sensor}")
        prob, x0 = carry_parameters(ip, ix, dataset, options)
        warm_induced = options.induced and ip.options.induced
    else:
        prob = ImprovedProblem(dataset, layout, start.model.gain, options)
        x0 = np.zeros(prob.size)
        x0[:layout.size] = layout.pack_calibration(start)
        warm_induced = False
    if options.induced and not warm_induced:
        # start: beyond the rows' centroid, 0.15 m further from the source, with a small moment
        # (at zero moment the position has no gradient)
        s0 = prob.extra["induced"].start
        c = prob.poses(x0)[:, :3, 3].mean(axis=0)
        q0 = c * (1.0 + INDUCED_START_OFFSET_M / np.linalg.norm(c))
        x0[s0:s0 + 3] = q0 if options.induced_start is None else options.induced_start
        x0[s0 + 3:prob.extra["induced"].stop] = 1e-4
    free = np.r_[layout.free_indices(optimize, freeze), np.arange(layout.size, prob.size)]

    if options.induced and not warm_induced:
        # first the moments with the position held at its start (at a near-zero moment the
        # position's gradient is tiny and a free position wanders), then everything
        s0 = prob.extra["induced"].start
        x0, _ = fit_free_parameters(prob, x0, np.setdiff1d(free, np.arange(s0, s0 + 3)),
                                    tol=tol, max_nfev=max_nfev, compress=True)
    x, res = fit_free_parameters(prob, x0, free, tol=tol, max_nfev=max_nfev, compress=True)
    return ImprovedFit(prob, x, free, res)
