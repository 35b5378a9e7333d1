"""The pose-solving options in one record, checked once (:class:`SolveOptions`; the solvers
are made from it by :func:`openemt.solve.prepare`, docs/solve.md#one-solver-factory)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._errors import InputError
from ..field import solver_family
from ._hemisphere import DEFAULT_HEMISPHERE, hemisphere_vectors
from ._lm_starts import _bounds
from ._validity import (
    EXPLORE_RELATIVE_RESIDUAL,
    MAX_RANGE_M,
    MAX_RELATIVE_RESIDUAL,
    check_validity_options,
)

__all__ = ["DEFAULT", "SolveOptions"]

#: ``hemisphere`` of :class:`SolveOptions` meaning "the solver's own default": ``'+x'`` for a
#: dipole source, the board's front side (its coils' normal) for a finite-coil board.
DEFAULT = "default"

#: most iterations per sample (the solvers converge in 2-20; a limit beyond this only lets a
#: sample that does not converge run for minutes)
MAX_ITER_LIMIT = 10_000

#: start names: the dipole LM's and the board solver's
_STARTS = ("kim18", "svd", "kuipers", "track", "multistart", "grid", "cold")

def _positive(name, v, *, integer=False, finite=True):
    if integer:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise InputError(f"expected `{name}` >= 1 (an integer), got {v!r}")
        return
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InputError(f"expected a positive number for `{name}`, got {v!r}") from None
    if not (f > 0 and (np.isfinite(f) or not finite)):
        raise InputError(f"expected a positive number for `{name}`, got {v!r}")


@dataclass(frozen=True, eq=False)
class SolveOptions:
    """The pose-solving options, held and checked once.

    Attributes
    ----------
    hemisphere : 'default', None, str, (3,), (N,) str or (N, 3)
        Constraint ``t . n >= 0``: ``'default'`` is ``'+x'`` for a dipole source and the
        front side of a board; ``None`` no constraint (see :func:`~openemt.solve.solve_lm`).
    initial : None, start name or array
        The start when a call gives none: None is the solver's default (``'kim18'`` for the
        dipole LM, ``'track'`` for a board); a name (``'kim18'``, ``'svd'``, ``'kuipers'``,
        ``'track'``, ``'multistart'``; ``'grid'`` for a board) or start pose vectors.
    max_iter, xtol : None or number
        Iteration limit and step tolerance; None is the solver's default (100 and 1e-8 for the
        dipole LM, 50 and 1e-9 for a board).
    max_relative_residual, max_range, bounds, ambiguity_tol
        The validity rule (docs/solve.md#validity-rule); ``ambiguity_tol`` None is the
        solver's default (1e-9 for LM, 1e-6 for the closed forms).
    retries, retry_resnorm, explore_above, concentric_model, covariance, fallback
        As in :func:`~openemt.solve.solve_lm` (the dipole LM only).

    Examples
    --------
    >>> from openemt.solve import SolveOptions
    >>> opts = SolveOptions(max_iter=50)
    >>> opts.replace(bounds=0.4).to_dict()["bounds"], opts.max_iter
    (0.4, 50)
    >>> SolveOptions(max_range=-1)
    Traceback (most recent call last):
    ...
    openemt._errors.InputError: expected a positive number for `max_range`, got -1
    """

    hemisphere: object = DEFAULT
    initial: object = None
    max_iter: int | None = None
    max_relative_residual: float | None = MAX_RELATIVE_RESIDUAL
    max_range: float | None = MAX_RANGE_M
    retries: bool = True
    retry_resnorm: float | None = None
    explore_above: float | None = EXPLORE_RELATIVE_RESIDUAL
    concentric_model: object = None
    bounds: object = None
    xtol: float | None = None
    ambiguity_tol: float | None = None
    covariance: bool = False
    fallback: str | None = None

    def __post_init__(self):
        h = self.hemisphere
        if not (isinstance(h, str) and h == DEFAULT) and h is not None:
            a = None if isinstance(h, str) else np.asarray(h)
            if a is None or (a.dtype.kind in "iuf" and a.shape == (3,)):
                hemisphere_vectors(h, 1)            # one spec for all: checked now
            elif a.ndim not in (1, 2):
                raise InputError(f"expected a hemisphere spec, (3,), (N,) or (N, 3), got "
                                 f"shape {a.shape}")
        init = self.initial
        if isinstance(init, str) and init not in _STARTS:
            raise InputError(f"expected `initial` in {', '.join(map(repr, _STARTS))} or pose "
                             f"vectors (N, 6), got {init!r}")
        if self.max_iter is not None:
            _positive("max_iter", self.max_iter, integer=True)
            if self.max_iter > MAX_ITER_LIMIT:         # a non-converging sample would hang
                raise InputError(f"expected `max_iter` <= {MAX_ITER_LIMIT}, got "
                                 f"{self.max_iter!r}")
        check_validity_options(self.max_relative_residual, self.max_range)
        for name in ("max_relative_residual", "max_range"):   # None disables; inf means nothing
            v = getattr(self, name)
            if v is not None and not np.isfinite(float(v)):
                raise InputError(f"expected a finite positive `{name}` (None disables the "
                                 f"test), got {v!r}")
        if self.retry_resnorm is not None:
            try:
                r = float(self.retry_resnorm)
            except (TypeError, ValueError):
                r = np.nan
            if not (r > 0 and np.isfinite(r)):
                raise InputError(f"expected a finite positive `retry_resnorm`, got "
                                 f"{self.retry_resnorm!r}")
        if self.explore_above is not None:
            _positive("explore_above", self.explore_above, finite=False)
        if self.concentric_model is not None and \
                solver_family(self.concentric_model) != "dipole":
            raise InputError(f"expected `concentric_model` to be a DipoleModel, got "
                             f"{type(self.concentric_model).__name__}")
        _bounds(self.bounds)
        if self.xtol is not None:
            _positive("xtol", self.xtol)
        if self.ambiguity_tol is not None:
            try:
                a = float(self.ambiguity_tol)
            except (TypeError, ValueError):
                a = np.nan
            if not (a >= 0 and np.isfinite(a)):
                raise InputError(f"expected a finite `ambiguity_tol` >= 0, got "
                                 f"{self.ambiguity_tol!r}")
        if self.fallback is not None and not (isinstance(self.fallback, str)
                                              and self.fallback == "multistart"):
            raise InputError(f"expected fallback None or 'multistart', got {self.fallback!r}")

    @classmethod
    def of(cls, options=None, overrides=None) -> SolveOptions:
        """``options`` (a record, a dict or None) with ``overrides`` (a dict) applied."""
        if options is None:
            options = cls()
        elif isinstance(options, dict):
            options = cls()._with(options)
        elif not isinstance(options, cls):
            raise InputError(f"expected `options` to be a SolveOptions, a dict or None, got "
                             f"{type(options).__name__}")
        return options._with(overrides) if overrides else options

    def _with(self, kw: dict) -> SolveOptions:
        names = {f.name for f in dataclasses.fields(self)}
        bad = sorted(set(kw) - names)
        if bad:
            raise InputError(f"expected solve options among {', '.join(sorted(names))}, got "
                             f"{', '.join(map(repr, bad))}")
        return dataclasses.replace(self, **kw)

    def replace(self, **kw) -> SolveOptions:
        """A copy with the fields in ``kw`` replaced (checked again)."""
        return self._with(kw)

    def to_dict(self) -> dict:
        """The options as JSON-ready values (arrays as lists, a model by its shape)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "concentric_model" and v is not None:
                v = {"model": "dipole", "n_source": v.n_source, "n_sensor": v.n_sensor}
            elif isinstance(v, np.ndarray):
                v = v.tolist()
            elif isinstance(v, np.generic):
                v = v.item()
            out[f.name] = v
        return out

    def changed(self, names) -> list:
        """The fields among ``names`` whose value is not the default."""
        out = []
        for name in names:
            v, d = getattr(self, name), _DEFAULTS[name]
            if v is d:
                continue
            if isinstance(v, np.ndarray) or isinstance(d, np.ndarray) or v != d:
                out.append(name)
        return out

    def lm_kwargs(self) -> dict:
        """The keyword options of :class:`~openemt.solve._prepared.PreparedLM`, defaults
        resolved."""
        h = self.hemisphere
        return {"hemisphere": DEFAULT_HEMISPHERE if isinstance(h, str) and h == DEFAULT else h,
                "max_iter": 100 if self.max_iter is None else self.max_iter,
                "max_relative_residual": self.max_relative_residual,
                "max_range": self.max_range, "retries": self.retries,
                "retry_resnorm": self.retry_resnorm, "explore_above": self.explore_above,
                "concentric_model": self.concentric_model, "bounds": self.bounds,
                "xtol": 1e-8 if self.xtol is None else self.xtol,
                "ambiguity_tol": 1e-9 if self.ambiguity_tol is None else self.ambiguity_tol}


_DEFAULTS = {f.name: f.default for f in dataclasses.fields(SolveOptions)}
