"""The README's Python blocks run as written (from a scratch folder) and print what it says."""

import pytest
from _readme_blocks import README, readme_blocks


def _python_blocks():
    return [code for _, code in readme_blocks("python")]


def test_readme_has_a_python_quick_start():
    assert _python_blocks()


@pytest.mark.parametrize("index", range(len(_python_blocks())))
def test_readme_python_block_runs(index, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__readme__"}
    code = compile(_python_blocks()[index], f"README.md block {index}", "exec")
    exec(code, namespace)  # noqa: S102 - the README's own example, run as a user would
    if "summary" in namespace:  # the quick start: the paper's Table II default row
        s = namespace["summary"]
        assert s["n"] == 1896
        assert s["trans_rms_mm"] == pytest.approx(0.41555, abs=5e-4)
        assert s["rot_rms_deg"] == pytest.approx(0.27262, abs=5e-4)
        assert "1896 poses: 0.416 mm, 0.273 deg RMS" in capsys.readouterr().out
        assert (tmp_path / "errors.png").stat().st_size > 1000


def test_readme_links_every_docs_page():
    text = README.read_text()
    pages = sorted(p.name for p in (README.parent / "docs").glob("*.md"))
    assert pages
    missing = [p for p in pages if f"(docs/{p})" not in text]
    assert not missing, f"docs pages not linked from README.md: {missing}"
