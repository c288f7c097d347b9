"""fcmpc-bench's sections run each in a fresh interpreter, from the source tree given."""
from __future__ import annotations

import os

import pytest

from fcmpc.bench.isolated import SectionRunError, run_sections, sections_module
from fcmpc.bench.reference import REPO


def _tree(tmp_path, body: str):
    package = tmp_path / "fcmpc" / "bench"
    package.mkdir(parents=True)
    (package.parent / "__init__.py").write_text("", encoding="utf-8")
    (package / "__init__.py").write_text("", encoding="utf-8")
    (package / "sections.py").write_text(body, encoding="utf-8")
    return tmp_path


def test_the_trees_own_sections_run_and_their_rows_come_back_whole(tmp_path):
    tree = _tree(tmp_path, "import os, sys\n"
                           "def bench_here():\n"
                           "    return [('where', __file__, str(os.getpid()), 'x'), ('short', '1.5 us')]\n"
                           "def bench_broken():\n"
                           "    raise RuntimeError('no sensor')\n")
    rows = run_sections(tree, ["bench_here", "bench_broken", "bench_missing"])
    assert rows[0][0] == "where" and rows[0][1] == str(tree / "fcmpc" / "bench" / "sections.py")   # the tree's module
    assert rows[0][2] != str(os.getpid())                                          # in a child
    assert rows[1] == ("short", "1.5 us", "", "")                                                # padded to four
    assert rows[2][0] == "bench_broken" and rows[2][1] == "FAILED: RuntimeError: no sensor"
    assert rows[3][0] == "bench_missing" and rows[3][1].startswith("FAILED: AttributeError")


def test_a_tree_whose_benchmarks_cannot_be_imported_is_one_clear_error(tmp_path):
    tree = _tree(tmp_path, "raise ImportError('numpy is missing')\n")
    with pytest.raises(SectionRunError, match="numpy is missing"):
        run_sections(tree, ["bench_here"])


def test_an_older_tree_keeps_its_benchmarks_in_scripts_bench(tmp_path):
    assert sections_module(tmp_path) == "scripts.bench"
    (tmp_path / "fcmpc_bench").mkdir()
    (tmp_path / "fcmpc_bench" / "sections.py").write_text("", encoding="utf-8")
    assert sections_module(tmp_path) == "fcmpc_bench.sections"
    assert sections_module(REPO) == "fcmpc.bench.sections"
