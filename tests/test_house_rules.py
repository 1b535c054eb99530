"""Static checks of the code's shape (docs/architecture.md, "House rules").

- No function in ``nav/`` or ``vision/`` is longer than ``MAX_LINES`` lines (numba kernels
  included), so that each can be read whole.
- No comment or docstring in ``nav/``, ``vision/`` or ``scenarios/`` tells the history of the code
  (issue numbers, sessions, before/after timings): that belongs in commit messages and
  docs/performance.md.
- ``nav`` and ``vision`` import nothing from ``scenarios`` (the arrows point one way).
"""
import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80
PURE = ("nav", "vision")

#: phrases that narrate history or timing runs rather than explain the code
HISTORY = re.compile(
    r"\bissue\s*#?\d+|\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh)"
    r"\s+session\b|\bsession\s+\d+|\bprevious implementation\b|\bformer implementation\b"
    r"|\bthree runs\b|\balternating runs\b|\bfell from\b", re.IGNORECASE)


def _py_files(*packages):
    for p in packages:
        yield from sorted((ROOT / p).rglob("*.py"))


def _long_functions(path: Path, root: Path = ROOT):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            n = node.end_lineno - first + 1
            if n > MAX_LINES:
                yield f"{path.relative_to(root)}:{node.lineno} {node.name} ({n} lines)"


def _comments_and_docstrings(path: Path):
    src = path.read_text()
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT or (tok.type == tokenize.STRING and tok.string.lstrip("rbuRBU").startswith(('"""', "'''"))):
            yield tok.start[0], tok.string


def test_functions_fit_on_a_screen():
    long = [f for p in _py_files(*PURE) for f in _long_functions(p)]
    assert not long, "functions over %d lines:\n" % MAX_LINES + "\n".join(long)


def test_long_function_rule_detects_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_LINES))
    f = tmp_path / "m.py"
    f.write_text(f"def short():\n    return 1\n\n\ndef long():\n{body}\n    return 0\n")
    assert [s.split()[1] for s in _long_functions(f, tmp_path)] == ["long"]


def test_no_history_in_comments():
    hits = [f"{p.relative_to(ROOT)}:{line}: {HISTORY.search(text).group(0)!r}"
            for p in _py_files("nav", "vision", "scenarios")
            for line, text in _comments_and_docstrings(p) if HISTORY.search(text)]
    assert not hits, "comments or docstrings that narrate history:\n" + "\n".join(hits)


@pytest.mark.parametrize("text,bad", [("# see issue 7 for the timing", True), ("# sixth session: faster", True),
                                      ("# 003, eq. (33): the nadir", False)])
def test_history_pattern(text, bad):
    assert bool(HISTORY.search(text)) is bad


def test_pure_packages_do_not_import_scenarios():
    hits = []
    for p in _py_files(*PURE):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            hits += [f"{p.relative_to(ROOT)}:{node.lineno} {n}" for n in names if n.split(".")[0] == "scenarios"]
    assert not hits, "\n".join(hits)


def _packages_on_disk():
    """Every package folder of nav, vision and scenarios (a folder with ``__init__.py``)."""
    return {str(p.parent.relative_to(ROOT)) + "/" for top in ("nav", "vision", "scenarios")
            for p in (ROOT / top).rglob("__init__.py") if "__pycache__" not in p.parts}


def _folders_in_table(text: str):
    return set(re.findall(r"^\| `([\w/]+/)` \|", text, re.MULTILINE))


def test_readme_and_architecture_tables_match_the_tree():
    on_disk = _packages_on_disk() - {"scenarios/library/"}
    readme = _folders_in_table((ROOT / "README.md").read_text())
    arch = _folders_in_table((ROOT / "docs" / "architecture.md").read_text())
    assert on_disk <= readme, f"packages missing from README's layout table: {sorted(on_disk - readme)}"
    assert {f for f in readme if (ROOT / f).is_dir()} == readme, "README names folders that do not exist"
    assert on_disk - {"nav/", "vision/", "scenarios/"} <= arch | {"scenarios/"}, sorted(on_disk - arch)
    assert all((ROOT / f).is_dir() for f in arch), "docs/architecture.md names folders that do not exist"
