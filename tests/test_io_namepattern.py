"""File-name patterns from data folders are matched in linear time, never by backtracking."""

import random
import re
import shutil
import time

import pytest

from openemt._errors import InputError
from openemt.cli import main
from openemt.io import import_ilemt_folder
from openemt.io._namepattern import compile_name_pattern

_SAFE = ["soZoutYup_seYoutZup_(md|ld).dat", "soXoutZup_seYoutZup_md.dat", r"^so.*_md\.dat$",
         "a[bc]+d?", "x.*y", "^abc$", "[^a]b", r"\d+_x", "(md|ld|sweep)$", "s.?o"]


def test_same_answers_as_re_on_the_safe_language():
    rng = random.Random(0)
    names = ["soZoutYup_seYoutZup_ld.dat", "soZoutYup_seYoutZup_md.dat", "abd", "acccd", "xxyy",
             "abc", "zabc", "bb", "12_x", "sweep", "sxo"]
    names += ["".join(rng.choice("abcdxyz_.mdlso1") for _ in range(rng.randint(0, 14)))
              for _ in range(2000)]
    for pattern in _SAFE:
        p, r = compile_name_pattern(pattern), re.compile(pattern)
        for name in names:
            assert p.search(name) == bool(r.search(name)), (pattern, name)


@pytest.mark.parametrize("evil", [r"^so.*_(a+)+$", "(a|b)*", "((a))", "a{2}", "(?=a)", r"(a)\1",
                                  "so(", "a)", "[ab", "*a"])
def test_dangerous_or_malformed_patterns_are_refused(evil):
    with pytest.raises(InputError, match="expected a file-name regular expression"):
        compile_name_pattern(evil)


def test_matching_time_is_linear_in_the_name():
    p = compile_name_pattern("^so.*_a*a*a*a*a*a*a*$")
    t0 = time.perf_counter()
    assert not p.search("so_" + "a" * 20000 + "b")
    assert time.perf_counter() - t0 < 5.0  # a backtracking engine takes longer than the universe


def test_crafted_options_file_is_refused_at_once(ilemt_dir, tmp_path):
    folder = tmp_path / "crafted"
    folder.mkdir()
    shutil.copy(ilemt_dir / "base_calibration.mat", folder)
    name = "so" + "a" * 40 + "!_se" + "a" * 4 + "_md.dat"
    shutil.copy(ilemt_dir / "soYoutZup_seYoutZup_md.dat", folder / name)
    (folder / "local_cal_options.m").write_text(
        "options.source_signs = {\n    '^so.*_(a+)+$' [-1 -1 1]\n    };\n")
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="quantified group"):
        import_ilemt_folder(folder)
    assert time.perf_counter() - t0 < 5.0


def test_bad_sign_rule_on_the_command_line(ilemt_dir, tmp_path, capsys):
    rc = main(["import", "ilemt", str(ilemt_dir), "-o", str(tmp_path / "x.h5"),
               "--source-signs", "so(=1,1,1"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "unclosed '('" in err
