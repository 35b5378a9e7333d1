"""The "none" correction: poses pass through unchanged.

It is a method like the others so that "no correction" is fitted, scored held out and, when
nothing beats it, written and applied like any other correction (docs/correction.md#auto).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["IdentityCorrection", "fit_identity"]


@dataclass(frozen=True)
class IdentityCorrection:
    """No correction: ``predict`` returns its input."""

    def predict(self, xyz, R=None):
        return xyz, R

    def to_params(self) -> dict:
        return {}

    @classmethod
    def from_params(cls, p: dict) -> IdentityCorrection:
        return cls()


def fit_identity(measured_xyz, reference_xyz, measured_R=None, reference_R=None,
                 **options) -> IdentityCorrection:
    """The identity; fit options (folds, seed) are accepted and ignored."""
    return IdentityCorrection()
