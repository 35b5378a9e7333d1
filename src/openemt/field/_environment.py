"""Environment terms of a coupling model: what the workspace adds to the tracker's own field.

A calibration made with metal in place (a grid, a reference collection, the rig's patterns)
can carry, beside the model of the coils, terms for the environment and the acquisition:

* **induced dipoles** -- a conductive or magnetic object near the tracker carries, at each
  source coil's carrier, an induced moment ``mu_ki``. Its field reaches the sensor coils as
  that of a dipole at ``q_k`` (source frame), so ``C_ind[i, j] = sum_k`` the dipole coupling
  of a "source coil" ``i`` at ``q_k`` with moment ``mu_ki`` into sensor coil ``j``. The
  moment is complex per carrier: ``mu_ki exp(1j phi_ki)``, a real direction and amplitude
  times a phase ``phi_ki`` of dipole ``k`` at source coil ``i``'s carrier (an object's eddy
  currents lag the drive by a phase that differs per carrier frequency; a sphere's or a large
  sheet's response is exactly a complex scalar times a real direction). Without phases (terms
  fitted to real couplings, files written before phases existed) every moment is in phase
  with the drive, ``phi = 0``: what the signed real coupling sees. Virtual dipoles of this kind took a
  C-arm's distortion of an Anser field generator from 12.01 to 0.35 mm (Cavaliere and
  Cantillon-Murphy, IJCARS 2022); such metal distortions are reviewed by Kindratenko, Virtual
  Reality 5(3), 2000. The sensor coils are read as point dipoles: a dipole model's ``L_se``,
  ``M_se``, a board's sensor coil positions and axes (times its relative sensor gains).
* **gain non-linearity** -- a sensor channel ``j`` whose gain changes with the signal level
  reads ``c_read`` with ``c_read (1 + beta_j |c_read|) = c`` (the calibration's
  linearisation, :func:`openemt.calibrate._rig.gain_linearise`, inverted exactly:
  ``c_read = 2 c / (1 + sqrt(1 + 4 beta_j |c|))``).
* **coupling offset** -- a pose-independent coupling ``C0`` (crosstalk) added before the gain.

So :class:`EnvironmentModel` predicts what is read::

    C_read = h_beta(base.coupling(P) + Re C_ind(P) + C0)

``coupling`` is this in-phase part (what every solver compares with the phase-calibrated
real coupling); :meth:`EnvironmentModel.complex_coupling` adds the quadrature
``1j * s Im C_ind(P)``, the induced dipoles' quadrature scaled by the same gain factor
``s = h_beta(c) / c`` of the in-phase coupling ``c`` (the tracker's base field is in phase).

It is a coupling model like every other (:class:`openemt.field.CouplingModel`): its pose and
parameter Jacobians are analytic, a dipole base declares the ``dipole-refined`` solver family
(the compiled dipole solver, then refined under the whole model) and any other base the
interface-level LM, so every solver path uses it unchanged. The terms are stored in a
calibration's ``extra["environment"]`` (docs/calibration-format.md#environment-terms).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError

__all__ = ["EnvironmentModel", "EnvironmentTerms", "axis_poses", "read_gain", "sensor_dipoles"]


#: Farthest induced dipole position a calibration may carry (m): an effective position, often
#: beyond the workspace (1.4 m on cal_9_15), never kilometres away (a damaged file).
MAX_DIPOLE_DISTANCE_M = 100.0


def read_gain(C, beta):
    """What a channel of gain non-linearity ``beta`` reads for a coupling ``C``: ``h`` with
    ``h (1 + beta |h|) = C`` (NaN where no real reading exists, ``1 + 4 beta |C| < 0``),
    and ``dh/dC``.

    Examples
    --------
    >>> import numpy as np
    >>> h, _ = read_gain(np.array([[[2.4, -1.0]]]), np.array([0.1, 0.0]))
    >>> h.round(12).tolist()
    [[[2.0, -1.0]]]
    """
    C = np.asarray(C, dtype=np.float64)
    b = np.asarray(beta, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        s = np.sqrt(1.0 + 4.0 * b * np.abs(C))
    return 2.0 * C / (1.0 + s), 1.0 / s


@dataclass(frozen=True, eq=False)
class EnvironmentTerms:
    """The environment terms of a calibration (see the module doc); all optional.

    Attributes
    ----------
    positions : ndarray, shape (K, 3)
        Induced dipole positions (m, source frame).
    moments : ndarray, shape (K, n_source, 3)
        Induced moment of each dipole at each source coil's carrier (coupling units of the
        model, as the source moments ``M_so`` of a dipole model); with ``phases``, its
        amplitude (the complex moment is ``moments * exp(1j * phases[..., None])``).
    gain_beta : ndarray, shape (n_sensor,) or None
        Gain non-linearity per sensor channel (per unit coupling).
    offset : ndarray, shape (n_source, n_sensor) or None
        Pose-independent coupling offset.
    phases : ndarray, shape (K, n_source) or None
        Phase (rad) of each induced moment at each source coil's carrier; None: in phase
        (real moments).
    """

    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    moments: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    gain_beta: np.ndarray | None = None
    offset: np.ndarray | None = None
    phases: np.ndarray | None = None

    def __post_init__(self):
        try:
            q = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
            mu = np.asarray(self.moments, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("expected induced dipole positions (K, 3) and moments (K, "
                             "n_source, 3) as numbers") from None
        if mu.size == 0:
            mu = np.zeros((q.shape[0], 0, 3))
        if mu.ndim != 3 or mu.shape[0] != q.shape[0] or mu.shape[2] != 3:
            raise InputError(f"expected induced dipole moments of shape (K, n_source, 3) for "
                             f"{q.shape[0]} position(s), got shape {mu.shape}")
        for name, v in (("induced dipole positions", q), ("induced dipole moments", mu)):
            if not np.all(np.isfinite(v)):
                raise InputError(f"expected finite {name}, got NaN or inf")
        object.__setattr__(self, "positions", q)
        object.__setattr__(self, "moments", mu)
        if np.abs(q).max(initial=0.0) > MAX_DIPOLE_DISTANCE_M:
            raise InputError(f"expected induced dipole positions within "
                             f"{MAX_DIPOLE_DISTANCE_M:g} m of the source, got "
                             f"{np.abs(q).max():.3g} m")
        for name, key in (("gain_beta", "gain_nonlinearity"), ("offset", "coupling_offset")):
            v = getattr(self, name)
            if v is not None:
                try:
                    v = np.asarray(v, dtype=np.float64)
                except (TypeError, ValueError):
                    raise InputError(f"expected numbers in the environment's `{key}`, got "
                                     f"{type(v).__name__}") from None
                if not np.all(np.isfinite(v)):
                    raise InputError(f"expected finite environment `{key}`, got NaN or inf")
                object.__setattr__(self, name, v)
        if self.phases is not None:
            try:
                ph = np.asarray(self.phases, dtype=np.float64)
            except (TypeError, ValueError):
                raise InputError(f"expected induced dipole phases as numbers, got "
                                 f"{type(self.phases).__name__}") from None
            if ph.size == 0 and mu.shape[0] == 0:
                ph = np.zeros(mu.shape[:2])
            if ph.shape != mu.shape[:2]:
                raise InputError(f"expected induced dipole phases of shape {mu.shape[:2]} "
                                 f"(one per dipole and source coil), got shape {ph.shape}")
            if not np.all(np.isfinite(ph)):
                raise InputError("expected finite induced dipole phases, got NaN or inf")
            object.__setattr__(self, "phases", ph)

    @property
    def has_quadrature(self) -> bool:
        """The induced moments carry phases (a quadrature part)."""
        return self.phases is not None and self.n_dipoles > 0

    def in_phase_moments(self) -> np.ndarray:
        """``(K, n_source, 3)``: the real part of the induced moments (the moments
        themselves without phases)."""
        return self.moments if self.phases is None else \
            self.moments * np.cos(self.phases)[..., None]

    def quadrature_moments(self) -> np.ndarray:
        """``(K, n_source, 3)``: the imaginary part of the induced moments (zero without
        phases)."""
        return np.zeros_like(self.moments) if self.phases is None else \
            self.moments * np.sin(self.phases)[..., None]

    @property
    def n_dipoles(self) -> int:
        return int(self.positions.shape[0])

    @property
    def empty(self) -> bool:
        """No term at all (the wrapper would be the base model)."""
        return self.n_dipoles == 0 and self.gain_beta is None and self.offset is None

    def names(self) -> list:
        """The terms present, as ``--environment`` spells them (``dipoles:K``, ``gain``,
        ``offset``)."""
        out = [f"dipoles:{self.n_dipoles}"] if self.n_dipoles else []
        return out + (["gain"] if self.gain_beta is not None else []) + \
            (["offset"] if self.offset is not None else [])

    def check(self, n_source: int, n_sensor: int, where: str = "") -> EnvironmentTerms:
        """``self`` if its shapes fit a model of ``n_source`` x ``n_sensor`` coils, else an
        InputError."""
        if self.n_dipoles and self.moments.shape[1] != n_source:
            raise InputError(f"{where}expected induced dipole moments for {n_source} source "
                             f"coils, got {self.moments.shape[1]}")
        if self.gain_beta is not None and self.gain_beta.shape != (n_sensor,):
            raise InputError(f"{where}expected `gain_nonlinearity` of shape ({n_sensor},), got "
                             f"{self.gain_beta.shape}")
        if self.offset is not None and self.offset.shape != (n_source, n_sensor):
            raise InputError(f"{where}expected `coupling_offset` of shape ({n_source}, "
                             f"{n_sensor}), got {self.offset.shape}")
        return self

    def with_phases(self) -> EnvironmentTerms:
        """These terms with phases (zero where there were none): the start of a fit to
        complex couplings."""
        if self.phases is not None:
            return self
        return EnvironmentTerms(self.positions, self.moments, self.gain_beta, self.offset,
                                np.zeros(self.moments.shape[:2]))

    def to_dict(self) -> dict:
        """JSON-ready form (a calibration's ``extra["environment"]``)."""
        dips = [{"position": q.tolist(), "moments": m.tolist()}
                for q, m in zip(self.positions, self.moments)]
        if self.phases is not None:
            for d, ph in zip(dips, self.phases):
                d["phases_rad"] = ph.tolist()
        return {"induced_dipoles": dips,
                "gain_nonlinearity": None if self.gain_beta is None else
                self.gain_beta.tolist(),
                "coupling_offset": None if self.offset is None else self.offset.tolist()}

    @classmethod
    def from_dict(cls, d) -> EnvironmentTerms:
        """The terms of :meth:`to_dict` (or of an improved rig calibration's ``extra["rig"]``:
        ``induced_dipole``, ``gain_nonlinearity``, ``coupling_offset``)."""
        if not isinstance(d, dict):
            raise InputError(f"expected the environment terms as an object, got "
                             f"{type(d).__name__}")
        dips = d.get("induced_dipoles")
        if dips is None and d.get("induced_dipole") is not None:
            dips = [d["induced_dipole"]]
        dips = dips or []
        try:
            q = np.array([x["position"] for x in dips], dtype=np.float64).reshape(-1, 3)
            mu = np.array([x["moments"] for x in dips], dtype=np.float64)
            has = [x.get("phases_rad") is not None for x in dips]
            ph = np.array([x["phases_rad"] for x in dips], dtype=np.float64) \
                if dips and all(has) else None
        except (TypeError, KeyError, ValueError, AttributeError):
            raise InputError("expected induced dipoles as objects with `position` (3 numbers), "
                             "`moments` (one 3-vector per source coil) and optionally "
                             "`phases_rad` (one number per source coil)") from None
        if any(has) and not all(has):
            raise InputError("expected `phases_rad` on every induced dipole or on none, got "
                             "them on some")
        return cls(q, mu if mu.size else np.zeros((q.shape[0], 0, 3)),
                   d.get("gain_nonlinearity"), d.get("coupling_offset"), ph)

    @property
    def dipole_size(self) -> int:
        """Parameters of one induced dipole: ``q``, the moments, the phases if any."""
        ns = self.moments.shape[1]
        return 3 + 3 * ns + (ns if self.phases is not None else 0)

    def vector(self) -> np.ndarray:
        """Flat parameters: per dipole ``q`` then its moments (then its phases, if any), then
        ``beta``, then ``C0``."""
        parts = [np.r_[q, m.ravel()] for q, m in zip(self.positions, self.moments)]
        if self.phases is not None:
            parts = [np.r_[p, ph] for p, ph in zip(parts, self.phases)]
        if self.gain_beta is not None:
            parts.append(self.gain_beta)
        if self.offset is not None:
            parts.append(self.offset.ravel())
        return np.concatenate(parts) if parts else np.zeros(0)

    def with_vector(self, v) -> EnvironmentTerms:
        v = np.asarray(v, dtype=np.float64)
        K, ns = self.n_dipoles, self.moments.shape[1]
        k = 0
        q, mu = np.empty((K, 3)), np.empty((K, ns, 3))
        ph = None if self.phases is None else np.empty((K, ns))
        for d in range(K):
            q[d] = v[k:k + 3]
            mu[d] = v[k + 3:k + 3 + 3 * ns].reshape(ns, 3)
            if ph is not None:
                ph[d] = v[k + 3 + 3 * ns:k + 3 + 4 * ns]
            k += self.dipole_size
        beta = off = None
        if self.gain_beta is not None:
            beta = v[k:k + self.gain_beta.size]
            k += self.gain_beta.size
        if self.offset is not None:
            off = v[k:k + self.offset.size].reshape(self.offset.shape)
        return EnvironmentTerms(q, mu, beta, off, ph)


def sensor_dipoles(base) -> tuple[float, np.ndarray, np.ndarray]:
    """``(gain, L (3, n_sensor), M (3, n_sensor))``: the sensor coils of ``base`` as point
    dipoles in the sensor frame (a dipole model's own; a board's coil positions and axes times
    its relative sensor gains, with gain 1)."""
    dip = getattr(base, "dipole", base)
    if hasattr(dip, "L_se") and hasattr(dip, "M_se") and hasattr(dip, "gain"):
        try:
            return float(dip.gain), np.asarray(dip.L_se), np.asarray(dip.M_se)
        except (AttributeError, InputError):
            pass
    board = getattr(base, "board", None)
    sensor = getattr(board, "sensor", None)
    if sensor is None:
        raise InputError(f"expected a model whose sensor coils are known (a dipole model or a "
                         f"board) for induced dipoles, got a {getattr(base, 'kind', '?')!r} "
                         f"model")
    g = getattr(base, "sensor_gains", None)
    g = np.ones(base.n_sensor) if g is None else np.asarray(g, dtype=np.float64)
    return 1.0, np.asarray(sensor.coil_positions()).T, np.asarray(sensor.coil_axes()).T * g


def axis_poses(points, axes) -> np.ndarray:
    """Poses ``(N, 4, 4)`` of a single-coil sensor at ``points (N, 3)`` whose z axis is the
    unit ``axes (N, 3)`` (the smallest rotation from z): grid data as poses."""
    from ..geometry import pose_from_vector, rotvec_between

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    return pose_from_vector(np.c_[pts, rotvec_between(np.array([0.0, 0.0, 1.0]), u)])


class EnvironmentModel:
    """A coupling model ``base`` plus environment terms ``terms`` (:class:`EnvironmentTerms`):
    ``C_read = h_beta(base.coupling(P) + C_ind(P) + C0)`` (module doc). Implements
    :class:`openemt.field.CouplingModel`; ``params`` are the base's followed by
    ``terms.vector()`` (groups ``induced``, ``gain_beta``, ``offset``)."""

    kind = "environment"

    def __init__(self, base, terms: EnvironmentTerms):
        from ._dipole import DipoleModel

        self.base = base
        self.terms = terms.check(base.n_source, base.n_sensor)
        gain, L, M = sensor_dipoles(base) if terms.n_dipoles else (1.0, None, None)

        def dipoles(moments):
            return [DipoleModel(gain=gain, L_so=np.repeat(q[:, None], base.n_source, axis=1),
                                M_so=mu.T, L_se=L, M_se=M)
                    for q, mu in zip(terms.positions, moments)]

        # the in-phase part of the induced moments (the moments themselves without phases)
        # and, with phases, the quadrature part
        self._induced = dipoles(terms.in_phase_moments())
        self._quadrature = dipoles(terms.quadrature_moments()) if terms.has_quadrature \
            else []
        family = getattr(base, "solver_family", "model")
        if hasattr(base, "dipole") or family == "dipole":
            self.dipole = getattr(base, "dipole", base)
            self.solver_family = "dipole-refined"
        elif family == "planar":
            # a board read by a single coil: its compiled 5-DOF solver (and cold start from
            # the seed grid), then refined under the whole model
            self.planar = base
            self.solver_family = "planar-refined"
        else:
            self.solver_family = "model"

    # -- what the model predicts --------------------------------------------------------------
    @property
    def n_source(self) -> int:
        return self.base.n_source

    @property
    def n_sensor(self) -> int:
        return self.base.n_sensor

    @property
    def dof(self) -> int:
        return self.base.dof

    @property
    def cold_start(self) -> str:
        return self.base.cold_start

    @property
    def gain(self):
        return getattr(self.base, "gain", 1.0)

    @property
    def n_coils(self) -> int:
        """A board's source coil count (the 5-DOF grid scoring's interface)."""
        return self.base.n_coils

    def coupling_points(self, points, axes) -> np.ndarray:
        """Couplings ``(N, n_source)`` into a single-coil sensor at ``points (N, 3)`` with
        ``axes (N, 3)`` (a board's interface for grid data), environment terms included."""
        if self.n_sensor != 1:
            raise InputError(f"expected a model of a single-coil sensor for couplings at "
                             f"points and axes, got {self.n_sensor} sensor coils")
        return self.coupling(axis_poses(points, axes))[:, :, 0]

    def linear_coupling(self, poses) -> np.ndarray:
        """The couplings before the gain non-linearity: base, induced dipoles and offset."""
        from ..geometry import check_poses

        P = np.asarray(check_poses(poses), dtype=np.float64).reshape(-1, 4, 4)
        C = np.array(self.base.coupling(P), dtype=np.float64)
        for d in self._induced:
            C += d.coupling(P)
        if self.terms.offset is not None:
            C += self.terms.offset
        return C

    def coupling(self, poses) -> np.ndarray:
        C = self.linear_coupling(poses)
        if self.terms.gain_beta is not None:
            C, _ = read_gain(C, self.terms.gain_beta)
        return C

    def complex_coupling(self, poses) -> np.ndarray:
        """The complex couplings read (phase-calibrated): :meth:`coupling` as the real part,
        the induced dipoles' quadrature (scaled by the gain factor of the in-phase coupling)
        as the imaginary part, zero without phases."""
        from ..geometry import check_poses

        P = np.asarray(check_poses(poses), dtype=np.float64).reshape(-1, 4, 4)
        C = self.linear_coupling(P)
        Q = np.zeros_like(C)
        for d in self._quadrature:
            Q += d.coupling(P)
        if self.terms.gain_beta is not None:
            h, _ = read_gain(C, self.terms.gain_beta)
            with np.errstate(invalid="ignore", divide="ignore"):
                s = np.where(C != 0, h / np.where(C != 0, C, 1.0), 1.0)
            return h + 1j * (Q * s)
        return C + 1j * Q

    def quadrature_jacobians(self, poses):
        """``(Q, dQ)``: the quadrature read (:meth:`complex_coupling`'s imaginary part,
        ``(N, n_source, n_sensor)``) and its gradient with respect to the environment terms'
        vector (``terms.vector()``, the base's parameters held), ``(N, n_source, n_sensor,
        n_terms)``: what a fit of the terms to complex couplings needs."""
        from ._dipole import coupling_jacobians

        P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        t = self.terms
        ns = self.n_source
        c_lin = self.linear_coupling(P)
        n, _, ne = c_lin.shape
        dQ = np.zeros((n, ns, ne, t.vector().size))
        dRe = np.zeros_like(dQ)              # the in-phase linear coupling's, for the gain
        Q = np.zeros_like(c_lin)
        k = 0
        for d, (di, dq) in enumerate(zip(self._induced, self._quadrature)):
            ji, jq = coupling_jacobians(di, P), coupling_jacobians(dq, P)
            Q += jq.C
            c, sn = np.cos(t.phases[d]), np.sin(t.phases[d])
            dQ[..., k:k + 3] = jq.d_L_so
            dRe[..., k:k + 3] = ji.d_L_so
            for i in range(ns):
                m = slice(k + 3 + 3 * i, k + 6 + 3 * i)
                dQ[:, i, :, m] = sn[i] * jq.d_M_so[:, i] if sn[i] else 0.0
                dRe[:, i, :, m] = c[i] * ji.d_M_so[:, i]
                # the dipole's moment at coil i times its phase: d/dphi of sin is cos
                dQ[:, i, :, k + 3 + 3 * ns + i] = ji.C[:, i]
                dRe[:, i, :, k + 3 + 3 * ns + i] = -jq.C[:, i]
            k += t.dipole_size
        if t.gain_beta is None:
            return Q, dQ
        if t.offset is not None:
            off = k + ne
            for i in range(ns):
                for jj in range(ne):
                    dRe[:, i, jj, off + i * ne + jj] = 1.0
        beta = t.gain_beta
        S = np.sqrt(1.0 + 4.0 * beta * np.abs(c_lin))
        s = 2.0 / (1.0 + S)
        ds_dc = -4.0 * beta * np.sign(c_lin) / (S * (1.0 + S) ** 2)
        dQ = dQ * s[..., None] + (Q * ds_dc)[..., None] * dRe
        for jj in range(ne):
            dQ[:, :, jj, k + jj] = -4.0 * Q[:, :, jj] * np.abs(c_lin[:, :, jj]) / (
                S[:, :, jj] * (1.0 + S[:, :, jj]) ** 2)
        return Q * s, dQ

    def linearise(self, C) -> np.ndarray:
        """Readings ``C`` with the gain non-linearity and the offset taken out (what the base
        model and the induced dipoles predict); unchanged without them."""
        C = np.asarray(C, dtype=np.float64)
        if self.terms.gain_beta is not None:
            C = C * (1.0 + self.terms.gain_beta * np.abs(C))
        if self.terms.offset is not None:
            C = C - self.terms.offset
        return C

    def jacobians(self, poses, params: bool = True):
        """:class:`~openemt.field.ModelJacobians` of the read couplings (analytic)."""
        from ._dipole import coupling_jacobians
        from ._protocol import ModelJacobians

        jb = self.base.jacobians(poses, params=params)
        C = np.array(jb.C, dtype=np.float64)
        dt = np.array(jb.d_translation, dtype=np.float64)
        dr = np.array(jb.d_rotation, dtype=np.float64)
        P = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        ji = [coupling_jacobians(d, P) for d in self._induced]
        for j in ji:
            C += j.C
            dt += j.d_translation
            dr += j.d_rotation
        if self.terms.offset is not None:
            C += self.terms.offset
        beta = self.terms.gain_beta
        scale = None
        if beta is not None:
            c_lin = C
            C, scale = read_gain(c_lin, beta)
            dt = dt * scale[..., None]
            dr = dr * scale[..., None]
        if not params:
            return ModelJacobians(C, dt, dr, None)
        n, ns, ne = C.shape
        nb = np.size(self.base.params)
        dp = np.zeros((n, ns, ne, nb + self.terms.vector().size))
        dp[..., :nb] = jb.d_params
        if ji and hasattr(self, "dipole"):
            # the induced fields are read by the base's sensor coils: their L_se, M_se
            # (the dipole parameters come first in a dipole or octupole base's vector)
            from ._dipole import CouplingJacobians, param_jacobian

            z = np.zeros_like(dt)
            sj = CouplingJacobians(C=C, d_translation=z, d_rotation=z, d_L_so=z, d_M_so=z,
                                   d_L_se=sum(j.d_L_se for j in ji),
                                   d_M_se=sum(j.d_M_se for j in ji))
            pj = param_jacobian(self.dipole, sj)
            dp[..., :pj.shape[-1]] += pj
        k = nb
        ph = self.terms.phases
        for d, j in enumerate(ji):
            dp[..., k:k + 3] = j.d_L_so
            for i in range(ns):
                dp[:, i, :, k + 3 + 3 * i:k + 6 + 3 * i] = j.d_M_so[:, i, :, :] if ph is None \
                    else np.cos(ph[d, i]) * j.d_M_so[:, i, :, :]
            if ph is not None:
                # the in-phase part mu cos(phi): d/dphi = -(the quadrature dipole's coupling)
                jq = self._quadrature[d].coupling(P)
                for i in range(ns):
                    dp[:, i, :, k + 3 + 3 * ns + i] = -jq[:, i]
            k += self.terms.dipole_size
        if scale is not None:
            dp[..., :k] *= scale[..., None]
            s = np.sqrt(1.0 + 4.0 * beta * np.abs(c_lin))
            g = -4.0 * c_lin * np.abs(c_lin) / (s * (1.0 + s) ** 2)
            for jj in range(ne):
                dp[:, :, jj, k + jj] = g[:, :, jj]
            k += ne
        if self.terms.offset is not None:
            sc = np.ones((n, ns, ne)) if scale is None else scale
            for i in range(ns):
                for jj in range(ne):
                    dp[:, i, jj, k + i * ne + jj] = sc[:, i, jj]
        return ModelJacobians(C, dt, dr, dp)

    # -- parameters ---------------------------------------------------------------------------
    @property
    def params(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.base.params, dtype=np.float64),
                               self.terms.vector()])

    def with_params(self, x) -> EnvironmentModel:
        x = np.asarray(x, dtype=np.float64)
        nb = np.size(self.base.params)
        return EnvironmentModel(self.base.with_params(x[:nb]), self.terms.with_vector(x[nb:]))

    def _env_groups(self) -> dict:
        nb = np.size(self.base.params)
        ns = self.n_source
        k = nb + self.terms.n_dipoles * self.terms.dipole_size
        out = {"induced": np.arange(nb, k)}
        if self.terms.gain_beta is not None:
            out["gain_beta"] = np.arange(k, k + self.n_sensor)
            k += self.n_sensor
        if self.terms.offset is not None:
            out["offset"] = np.arange(k, k + ns * self.n_sensor)
        return {g: v for g, v in out.items() if v.size}

    def split_params(self, x) -> dict:
        x = np.asarray(x, dtype=np.float64)
        nb = np.size(self.base.params)
        return {**self.base.split_params(x[:nb]),
                **{g: x[i] for g, i in self._env_groups().items()}}

    @property
    def parameter_groups(self) -> dict:
        return {**self.base.parameter_groups, **self._env_groups()}

    @property
    def gauge(self) -> np.ndarray:
        return self.base.gauge

    @property
    def fit_groups(self) -> tuple:
        return tuple(self.base.fit_groups) + tuple(self._env_groups())

    @property
    def fixed_groups(self) -> tuple:
        return tuple(self.base.fixed_groups)

    def parameter_label(self, i: int) -> str:
        nb = np.size(self.base.params)
        if i < nb:
            return self.base.parameter_label(i)
        for g, idx in self._env_groups().items():
            if i in idx:
                return f"{g}[{int(i - idx[0])}]"
        raise IndexError(i)

    def parameter_unit(self, i: int) -> tuple:
        nb = np.size(self.base.params)
        if i < nb:
            return self.base.parameter_unit(i)
        return ("", 1.0)

    def packed(self):
        return self.base.packed()

    def describe(self) -> dict:
        d = self.base.describe() if hasattr(self.base, "describe") else {}
        return {**d, "model_kind": self.kind, "base_kind": self.base.kind,
                "environment": self.terms.names()}

    def __getattr__(self, name):
        # a dipole base's arrays, for code that reads them (the concentric start, reports)
        if name in ("L_so", "M_so", "L_se", "M_se", "is_concentric"):
            return getattr(self.__dict__["base"], name)
        raise AttributeError(name)
