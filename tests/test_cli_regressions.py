"""Command-line values that used to crash or pass silently: now one error line and exit 2."""

import pytest

from openemt.cli import main


@pytest.mark.parametrize("argv, expected", [
    (["track", "--duration", "inf", "--fast", "--no-igtl"], "finite --duration"),
    (["track", "--duration", "nan", "--fast", "--no-igtl"], "finite --duration"),
    (["track", "--duration", "0.05", "--fast", "--no-igtl", "--distortion-threshold", "nan"],
     "--distortion-threshold >= 0"),
])
def test_bad_numbers_are_refused(argv, expected, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and expected in err[0]


def test_nan_smoothing_is_refused(tmp_path, capsys):
    import numpy as np

    from openemt.bench._correct import distorted_poses
    from openemt.io import write_poses_csv

    meas, ref = distorted_poses(60, np.random.default_rng(0))
    pairs = write_poses_csv(tmp_path / "pairs.csv", meas, reference=ref)
    out = tmp_path / "corr.json"
    assert main(["correct", "fit", pairs, "--method", "rbf", "--smoothing", "nan", "-o", out]) == 2
    assert "finite --smoothing >= 0" in capsys.readouterr().err
    assert not out.exists()


def test_huge_lookup_grid_is_refused(tmp_path, capsys):
    import numpy as np

    from openemt.bench._correct import distorted_poses
    from openemt.io import write_poses_csv

    meas, ref = distorted_poses(60, np.random.default_rng(0))
    pairs = write_poses_csv(tmp_path / "pairs.csv", meas, reference=ref)
    out = tmp_path / "corr.json"
    argv = ["correct", "fit", pairs, "--method", "grid", "--grid-shape", "1000,1000,1000",
            "-o", out]
    assert main(argv) == 2
    assert "at most MAX_GRID_NODES" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("fit", ["fit_grid", "fit_rbf"])
def test_library_refuses_nan_smoothing(fit):
    import numpy as np

    from openemt import correct
    from openemt._errors import InputError

    rng = np.random.default_rng(0)
    p = rng.uniform(-0.1, 0.1, (40, 3))
    with pytest.raises(InputError, match="finite `smoothing` >= 0"):
        getattr(correct, fit)(p, p + 1e-3, smoothing=float("nan"))
