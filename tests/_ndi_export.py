"""Writing NDI Toolbox exports in the layout real files have (for the tests)."""

from scipy.spatial.transform import Rotation

EM = "Port 10: NDI-MF2 610066   T6d0-S00108  s/n:37B31800 Channel:0"
EM2 = "Port 11: NDI-MF2 610066   T6d0-S00109  s/n:37B31801 Channel:0"
OPT = "Port 1: CAMP OT-Sensor-2013-05-08  s/n:38A1FC00"
FIELDS = ["Frame", "Face", "State", "Q0", "Qx", "Qy", "Qz", "Tx", "Ty", "Tz", "Error", "Markers"]
SENT = "-3.697314E28"


def header(labels):
    cells = ["Tools"]
    for lab in labels:
        cells += [lab] + FIELDS
    return "\t".join(cells)


def fields(label, frame, state, pose=None, err=0.1234, markers=0):
    if pose is None:
        return [label, str(frame), "0", state] + [SENT] * 7 + [SENT, str(markers)]
    q = Rotation.from_matrix(pose[:3, :3]).as_quat(scalar_first=True)
    t = pose[:3, 3] * 1e3
    return ([label, str(frame), "0", state] + [f"{v:.6f}" for v in q]
            + [f"{v:.4f}" for v in t] + [f"{err:.4f}", str(markers)])


def write_export(path, labels, poses, *, states=None, truncate=False, crlf=False, bom=False,
                 trailing=False, first_frame=1000):
    """Rows of all tools; ``states[(k, tool)]`` overrides the state of one tool in row k."""
    states = states or {}
    n = len(poses[0])
    lines = [header(labels) + ("\t" if trailing else "")]
    for k in range(n):
        cells = [str(len(labels))]
        for j, lab in enumerate(labels):
            st = states.get((k, j), "OK")
            cells += fields(lab, first_frame + k, st, poses[j][k] if st == "OK" else None)
        lines.append("\t".join(cells) + ("\t\t" if trailing else ""))
    if truncate:
        lines[-1] = lines[-1][: len(lines[-1]) // 2]
    text = ("\r\n" if crlf else "\n").join(lines) + ("\r\n" if crlf else "\n")
    if truncate:
        text = text.rstrip("\r\n")
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
