"""The examples in the public API's docstrings run and give what they say.

Every module listed here is run through :mod:`doctest` (as ``make test``
runs this file); a module must hold at least the number of examples given,
so examples cannot silently disappear.
"""

from __future__ import annotations

import doctest
import importlib

import pytest

#: module -> least number of examples it holds
MODULES = {
    "l3cli.cfa": 8,
    "l3cli.table": 5,
    "l3cli.colourspace": 3,
    "l3cli.classify.definition": 6,
    "l3cli.classify.kernel": 3,
    "l3cli.classify.levels": 4,
    "l3cli.classify.padding": 1,
    "l3cli.align.common": 3,
    "l3cli.metrics._common": 4,
    "l3cli.metrics.mtf": 1,
    "l3cli.metrics.psnr": 3,
    "l3cli.metrics.scielab": 1,
    "l3cli.evaluate.options": 2,
}


@pytest.mark.parametrize("name", sorted(MODULES))
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, verbose=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
    assert result.attempted >= MODULES[name], f"{name}: only {result.attempted} examples"


def test_at_least_ten_examples_in_all():
    assert sum(MODULES.values()) >= 10
