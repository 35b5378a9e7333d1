"""3D Slicer markups: .fcsv of the Slicer 3 fiducial lists, the 4.x markups files (numeric and
named coordinate systems, with and without a columns line) and .mrk.json are read alike."""

import json

import numpy as np
import pytest

from openemt._errors import InputError
from openemt.navigate import read_markups, read_tool_poses

RAS = np.array([[10.0, -20.5, 30.25], [-1.5, 2.0, 3.0], [100.0, 0.0, -50.0]])

SLICER3 = """# Fiducial List file /data/grid.fcsv
# version = 2
# name = grid
# numPoints = 3
# symbolScale = 5
# visibility = 1
# color = 0.4,1,1
# columns = label,x,y,z,sel,vis
{rows}"""

SLICER44 = """# Markups fiducial file version = 4.4
# CoordinateSystem = 0
# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID
{rows}"""

SLICER411_LPS = """# Markups fiducial file version = 4.11
# CoordinateSystem = LPS
# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID
{rows}"""

NO_COLUMNS = """# Markups fiducial file version = 4.6
# CoordinateSystem = 1
{rows}"""


def _rows_markups(points):
    return "".join(f"vtkMRMLMarkupsFiducialNode_{i},{p[0]},{p[1]},{p[2]},0,0,0,1,1,1,0,"
                   f"\"F-{i}, tip\",,vtkMRMLScalarVolumeNode1\n" for i, p in enumerate(points))


def _rows_slicer3(points):
    return "".join(f"F{i},{p[0]},{p[1]},{p[2]},1,1\n" for i, p in enumerate(points))


LPS = RAS * [-1, -1, 1]


@pytest.mark.parametrize("template, points, rows, version", [
    (SLICER3, RAS, _rows_slicer3, "fiducial-list 2"),
    (SLICER44, RAS, _rows_markups, "fcsv 4.4"),
    (SLICER411_LPS, LPS, _rows_markups, "fcsv 4.11"),
    (NO_COLUMNS, LPS, _rows_markups, "fcsv 4.6"),
])
def test_fcsv_versions(tmp_path, template, points, rows, version):
    path = tmp_path / "points.fcsv"
    path.write_text(template.format(rows=rows(points)))
    m = read_markups(path)
    np.testing.assert_allclose(m.points, 1e-3 * RAS, atol=1e-15)
    assert m.version == version
    assert len(m.labels) == 3
    if rows is _rows_markups:
        assert m.labels[1] == "F-1, tip"  # a quoted label with a comma


def _mrk(points, system, schema="1.0.3", extra=None):
    cps = [{"id": str(i), "label": f"F-{i}", "position": list(p),
            "orientation": [-1, 0, 0, 0, -1, 0, 0, 0, 1], "positionStatus": "defined"}
           for i, p in enumerate(points)]
    cps += extra or []
    node = {"type": "Fiducial", "coordinateSystem": system, "controlPoints": cps}
    if schema != "1.0.0":
        node["coordinateUnits"] = "mm"
    return {"@schema": "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/"
                       f"Markups/Resources/Schema/markups-schema-v{schema}.json#",
            "markups": [node]}


@pytest.mark.parametrize("schema, system, points", [("1.0.0", "LPS", LPS),
                                                     ("1.0.3", "RAS", RAS)])
def test_mrk_json(tmp_path, schema, system, points):
    undefined = [{"id": "9", "label": "F-9", "position": [0, 0, 0],
                  "positionStatus": "undefined"}]
    path = tmp_path / "points.mrk.json"
    path.write_text(json.dumps(_mrk(points, system, schema, undefined)))
    m = read_markups(path)
    np.testing.assert_allclose(m.points, 1e-3 * RAS, atol=1e-15)
    assert m.version == f"mrk.json {schema}"
    assert m.n_undefined == 1 and m.labels.tolist() == ["F-0", "F-1", "F-2"]


def test_markups_as_tool_poses_with_repeated_labels(tmp_path):
    path = tmp_path / "repeated.fcsv"
    rows = "".join(f"id{k},{p[0]},{p[1]},{p[2]},0,0,0,1,1,1,0,P{i},,\n"
                   for k in range(2) for i, p in enumerate(RAS))
    path.write_text(SLICER44.format(rows=rows))
    t = read_tool_poses(path)
    assert t.kind == "markups" and not t.has_orientation
    assert t.groups.tolist() == ["P0", "P1", "P2"] * 2
    np.testing.assert_allclose(t.poses[:3, :3, 3], 1e-3 * RAS)


@pytest.mark.parametrize("text, match", [
    ("1,2,3\n", "3D Slicer markups"),
    (SLICER44.format(rows="a,1,x,3,0,0,0,1,1,1,0,L,,\n"), "numbers x, y, z on line 4"),
    (SLICER44.format(rows=""), "at least one point"),
    ("# Markups fiducial file version = 4.11\n# CoordinateSystem = IJK\n", "CoordinateSystem"),
])
def test_bad_fcsv(tmp_path, text, match):
    path = tmp_path / "bad.fcsv"
    path.write_text(text)
    with pytest.raises(InputError, match=match):
        read_markups(path)


def test_bad_mrk_json(tmp_path):
    path = tmp_path / "bad.mrk.json"
    path.write_text(json.dumps({"markups": [{"controlPoints": [{"position": [1, "a", 3]}]}]}))
    with pytest.raises(InputError, match="3 finite numbers"):
        read_markups(path)
    path.write_text("[1, 2]")
    with pytest.raises(InputError, match="'markups' list"):
        read_markups(path)


@pytest.mark.parametrize("name", ["grid.fcsv", "grid.mrk.json"])
def test_mutated_markups_give_points_or_one_input_error(tmp_path, name):
    """Byte mutations of a valid file (the fuzz suite's mutator): every outcome is either
    finite points with one label each, or an InputError (a ValueError), never another
    exception."""
    import random

    from openemt_fuzz._fuzzcases import BYTE_OPS, mutate_bytes, random_ops

    path = tmp_path / name
    if name.endswith(".fcsv"):
        seed = SLICER411_LPS.format(rows=_rows_markups(LPS)).encode()
    else:
        seed = json.dumps(_mrk(RAS, "RAS")).encode()
    rng = random.Random(0)
    outcomes = {"ok": 0, "error": 0}
    for _ in range(300):
        path.write_bytes(mutate_bytes(seed, random_ops(rng, BYTE_OPS)))
        try:
            m = read_markups(path)
        except ValueError:
            outcomes["error"] += 1
            continue
        assert m.points.ndim == 2 and m.points.shape[1] == 3 and len(m.points) >= 1
        assert np.all(np.isfinite(m.points)) and len(m.labels) == len(m.points)
        outcomes["ok"] += 1
    assert outcomes["ok"] and outcomes["error"]
