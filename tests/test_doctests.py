"""The docstring examples of every module in ``l3cli/`` run as tests.

pytest collects them itself (``--doctest-modules`` over ``l3cli``, set in
``pyproject.toml``; the repository's ``conftest.py`` leaves out the ``export``
package where its optional extra, onnx, is absent). This file checks that the
collection cannot shrink silently: every module imports, and the package holds
at least as many examples as when this was written.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil
import tomllib

import l3cli
from tests.builders import REPO

#: examples in the package when this test was written (88 in 23 modules)
LEAST_EXAMPLES = 88


def _modules():
    for info in pkgutil.walk_packages(l3cli.__path__, "l3cli."):
        if info.name.startswith("l3cli.export"):
            try:
                import onnx  # noqa: F401
            except ImportError:
                continue
        yield importlib.import_module(info.name)


def test_every_module_imports_and_the_examples_are_all_there():
    finder = doctest.DocTestFinder()
    counts = {m.__name__: sum(len(t.examples) for t in finder.find(m)) for m in _modules()}
    assert sum(counts.values()) >= LEAST_EXAMPLES, counts
    assert counts["l3cli.cfa"] >= 8 and counts["l3cli.table"] >= 5


def test_pytest_runs_the_package_examples():
    opts = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert "l3cli" in opts["testpaths"] and "--doctest-modules" in opts["addopts"]
