"""File-name patterns from data folders are matched in linear time, never by backtracking."""

import random
import re
import shutil

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


@pytest.fixture
def steps(monkeypatch):
    """Counts the automaton's character tests (the work of a match), instead of timing it."""
    from openemt.io import _namepattern

    count = [0]
    accepts = _namepattern._Token.accepts

    def counted(self, ch):
        count[0] += 1
        return accepts(self, ch)

    monkeypatch.setattr(_namepattern._Token, "accepts", counted)
    return count


def test_matching_work_is_linear_in_the_name(steps):
    pattern = "^so.*_a*a*a*a*a*a*a*$"
    p = compile_name_pattern(pattern)
    n_tokens = len(p.alternatives[0][1])
    work = []
    for n in (1000, 2000, 4000):
        steps[0] = 0
        name = "so_" + "a" * n + "b"
        assert not p.search(name) and not re.search(pattern, "so_" + "a" * 10 + "b")
        # one pass over the name with at most one state per pattern position; a backtracking
        # engine tries every split of the a's among the seven a* (about n^7 / 7! steps)
        assert len(name) <= steps[0] <= (n_tokens + 1) * len(name)
        work.append(steps[0])
    assert work[2] - work[1] == pytest.approx(2 * (work[1] - work[0]), rel=0.01)


def test_crafted_options_file_is_refused_at_once(ilemt_dir, tmp_path, steps):
    folder = tmp_path / "crafted"
    folder.mkdir()
    shutil.copy(ilemt_dir / "base_calibration.mat", folder)
    name = "so" + "a" * 40 + "!_se" + "a" * 4 + "_md.dat"
    shutil.copy(ilemt_dir / "soYoutZup_seYoutZup_md.dat", folder / name)
    (folder / "local_cal_options.m").write_text(
        "options.source_signs = {\n    '^so.*_(a+)+$' [-1 -1 1]\n    };\n")
    with pytest.raises(InputError, match="quantified group"):
        import_ilemt_folder(folder)
    assert steps[0] == 0  # refused before any name was matched against it


def test_bad_sign_rule_on_the_command_line(ilemt_dir, tmp_path, capsys):
    rc = main(["import", "ilemt", str(ilemt_dir), "-o", str(tmp_path / "x.h5"),
               "--source-signs", "so(=1,1,1"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and "unclosed '('" in err
