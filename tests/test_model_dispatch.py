"""The model protocol does the dispatch: each coupling model declares its solver family and
cold start, ``prepare`` builds the solver through one registry keyed by the family, and a
calibration holds its full coupling model as an object."""

from __future__ import annotations

import numpy as np
import pytest

import openemt.solve._factory as factory
from openemt.board import BoardModel, DipoleOnlyError
from openemt.field import OctupoleModel, solver_family
from openemt.simulate import nominal_calibration, truth_calibration
from openemt.solve import SOLVER_FAMILIES, prepare


def test_models_declare_their_solver_family_and_cold_start():
    dip = truth_calibration("dipole-approx").model
    board = BoardModel.from_board("anser")
    six = nominal_calibration("anser-6dof").model
    octu = OctupoleModel(dip, np.full(3, 1e-5), np.zeros(3))
    from openemt.field import EnvironmentModel, EnvironmentTerms

    # a board with environment terms: its compiled 5-DOF solver, then a refinement under the
    # whole model
    env_board = EnvironmentModel(board, EnvironmentTerms(np.zeros((0, 3)),
                                                         np.zeros((0, board.n_source, 3)),
                                                         gain_beta=np.zeros(board.n_sensor)))
    assert [solver_family(m) for m in (dip, octu, board, six, env_board)] == \
        ["dipole", "dipole-refined", "planar", "board", "planar-refined"]
    assert set(SOLVER_FAMILIES) == {"dipole", "dipole-refined", "planar", "planar-refined",
                                    "board", "model"}
    assert solver_family(object()) == "model"                 # undeclared: the generic LM
    # the prepared solver says how a sample with no prior pose starts (the live pipeline's
    # first sample): the model's own cold start, or the dipole LM's concentric start
    assert prepare(dip).cold_start == "kim18"
    assert prepare(board).cold_start == board.cold_start == "grid"
    assert prepare(six).cold_start == six.cold_start
    assert prepare(dip, solver="svd").cold_start is None
    wide = truth_calibration("dipole-approx").model
    assert prepare(wide).cold_start in ("kim18", "multistart")


def test_prepare_dispatches_through_the_registry(monkeypatch):
    """A family's entry builds the solver: replacing it changes what prepare returns, for a
    model of any class that declares the family."""
    made = []

    def builder(model, solver, opts):
        made.append((type(model).__name__, solver))
        return "sentinel", None

    monkeypatch.setitem(factory.SOLVER_FAMILIES, "planar", builder)
    board = BoardModel.from_board("anser")
    assert prepare(board) == "sentinel" and made == [("BoardModel", "lm")]
    monkeypatch.setitem(factory.SOLVER_FAMILIES, "dipole", builder)
    assert prepare(truth_calibration("dipole-approx").model) == "sentinel"


def test_board_model_attribute_errors():
    board = BoardModel.from_board("anser")
    assert getattr(board, "no_such_attribute", None) is None   # a plain AttributeError
    with pytest.raises(DipoleOnlyError, match="dipole-model calibration"):
        board.M_so                                             # a dipole model's: bad input
    assert not hasattr(board, "L_so")
    assert board.solver_family == "planar" and board.cold_start == "grid"


def test_calibration_holds_its_octupole_model():
    cal = truth_calibration("dipole-approx")
    assert cal.coupling_model is cal.model                     # no extra terms: the model
    rig = {"octupole_k_so": [1e-5, 0.0, 2e-5], "octupole_k_se": [0.0, 0.0, 0.0]}
    imp = cal.replace(extra={"rig": rig})
    full = imp.coupling_model
    assert isinstance(full, OctupoleModel) and full is imp.coupling_model   # one object
    np.testing.assert_array_equal(full.k_so, rig["octupole_k_so"])
    assert solver_family(full) == "dipole-refined"


def test_no_isinstance_dipole_model_outside_field_and_the_registry():
    """The model protocol does the dispatch: outside openemt.field and the solver registry no
    code asks whether a model is a DipoleModel (it asks the model: ``kind``,
    ``solver_family``)."""
    import pathlib
    import re

    import openemt

    src = pathlib.Path(openemt.__file__).parent
    found = [f"{p.relative_to(src)}:{i}"
             for p in src.rglob("*.py")
             if p.parent.name != "field" and p.relative_to(src).as_posix() != "solve/_factory.py"
             for i, line in enumerate(p.read_text().splitlines(), 1)
             if re.search(r"isinstance\([^)]*\bDipoleModel\b", line)]
    assert found == []
