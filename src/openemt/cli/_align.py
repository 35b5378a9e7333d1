"""``openemt align MEASURED.h5 REFERENCE.h5 -o pairs.csv``: solve A_i X = Y B_i between two
pose recordings and write the pose pairs that ``openemt correct fit`` reads.

MEASURED holds the tracked tool of the tracker to correct (an EM sensor in the field-generator
frame), REFERENCE the rigidly attached reference tool (an optical marker in the camera frame,
or a robot flange in the base frame); both are pose datasets from ``openemt import ndi|poses``.
The reference is mapped onto the measured tool in the measured tracker's frame
(``Y B_i X^-1``, docs/alignment.md#the-model).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._errors import InputError
from . import command_help
from ._common import add_common, emit

__all__ = ["register", "run"]


def register(sub) -> None:
    p = sub.add_parser("align", help=command_help("align"),
                       description=__doc__.splitlines()[0])
    p.add_argument("measured", help="pose dataset (.h5) of the tracker to correct")
    p.add_argument("reference", help="pose dataset (.h5) of the reference tracker or robot")
    p.add_argument("-o", "--output", required=True,
                   help="pose-pair CSV to write (measured + ref_ columns, metres/radians)")
    p.add_argument("--match", choices=("order", "frame"), default="order",
                   help="pair rows by order (default) or by equal frame number")
    p.add_argument("--keep-outliers", action="store_true",
                   help="also write the pairs flagged as outliers")
    p.add_argument("--no-robust", action="store_true",
                   help="no outlier screening: plain least squares over all pairs")
    p.add_argument("--folds", type=int, default=5,
                   help="folds of the held-out check (0: none; at most 20)")
    p.add_argument("--seed", type=int, default=0)
    add_common(p)
    p.set_defaults(func=run)


def _frames(ds):
    f = ds.extra.get("frame")
    return None if f is None else np.asarray(f, dtype=np.int64)


def _fmt(P, se) -> str:
    from ..geometry import vector_from_pose

    v = vector_from_pose(P)
    t = ", ".join(f"{1e3 * a:.3f}+-{1e3 * s:.3f}" for a, s in zip(v[:3], se[:3]))
    r = ", ".join(f"{np.rad2deg(a):.3f}+-{np.rad2deg(s):.3f}" for a, s in zip(v[3:], se[3:]))
    return f"t [{t}] mm, rotvec [{r}] deg"


def run(args) -> int:
    from ..align import fit_axyb, pair_rows, reference_in_measured_frame
    from ..io import read_pose_dataset, write_poses_csv

    meas = read_pose_dataset(args.measured)
    ref = read_pose_dataset(args.reference)
    i, j, info = pair_rows(meas.n_samples, ref.n_samples, match=args.match,
                           measured_frame=_frames(meas), reference_frame=_frames(ref))
    A, B = meas.poses[i], ref.poses[j]
    finite = np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(B), axis=(1, 2))
    n_nonfinite = int((~finite).sum())
    A, B, i = A[finite], B[finite], i[finite]
    if args.folds and args.folds < 2:
        raise InputError(f"expected --folds 0 or >= 2, got {args.folds}")
    res = fit_axyb(A, B, robust=not args.no_robust, folds=args.folds, seed=args.seed)
    keep = np.ones(len(A), bool) if args.keep_outliers else res.inlier
    Ah = reference_in_measured_frame(B, res.X, res.Y)
    fr = _frames(meas)
    write_poses_csv(args.output, A[keep], Ah[keep],
                    frame=None if fr is None else fr[i][keep])
    s = res.summary()
    summary = {"output": str(Path(args.output)), **info, "n_pairs_nonfinite": n_nonfinite,
               **s, "n_written": int(keep.sum()),
               "outlier_rows_measured": i[~res.inlier].tolist()}
    human = [f"aligned {s['n']} pairs ({info['match']}): {s['n_outliers']} outliers"
             + (" (written)" if args.keep_outliers else " (not written)"),
             (f"  residual rms {s['residual_trans_rms_mm']:.3f} mm, "
              f"{s['residual_rot_rms_deg']:.3f} deg"),
             f"  X (reference tool -> measured tool): {_fmt(res.X, res.X_se)}",
             f"  Y (reference frame -> measured frame): {_fmt(res.Y, res.Y_se)}"]
    if s["held_out"]:
        human.insert(2, f"  held out ({s['held_out']['n_folds']}-fold) "
                        f"{s['held_out']['trans_rms_mm']:.3f} mm, "
                        f"{s['held_out']['rot_rms_deg']:.3f} deg")
    if res.condition > 1e6:
        summary["warning"] = "X or Y poorly determined: rotate the tools about more axes"
        human.append("warning: " + summary["warning"])
    human.append(f"  {int(keep.sum())} pairs -> {args.output}")
    emit(args, summary, human)
    return 0
