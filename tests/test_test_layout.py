"""The tests' own layout (tests/README.md): no test module imports another test
module (shared builders live in ``tests/builders.py``, fixtures in ``conftest.py``),
and every folder of tests is a package (unique module names)."""

from __future__ import annotations

import ast

from tests.builders import TESTS


def _imported(tree: ast.AST) -> list[str]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.append(node.module)
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
    return out


def test_no_test_module_imports_another():
    bad = []
    for path in TESTS.rglob("*.py"):
        for name in _imported(ast.parse(path.read_text(encoding="utf-8"))):
            last = name.rsplit(".", 1)[-1]
            if last.startswith("test_") or last == "conftest":
                bad.append(f"{path.relative_to(TESTS)} imports {name}")
    assert not bad, bad


def test_every_test_folder_is_a_package():
    folders = {p.parent for p in TESTS.rglob("test_*.py")}
    assert all((f / "__init__.py").exists() for f in folders), sorted(
        str(f) for f in folders if not (f / "__init__.py").exists())
