"""The user docs quote what the program does (issue 31): option defaults as the
command line has them, and the tutorial's scores as a run gives them."""

from __future__ import annotations

import re
from pathlib import Path

import click

from l3cli.cli.main import cli
from l3cli.defaults import PAIRS_LAYOUT, SIMULATION_LAYOUT

ROOT = Path(__file__).parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]

#: "(`--levels`, default 24)", "(`--patch`, odd, default 7 for pairs folders, 5 for
#: simulate folders)", "`--min-samples` (default 3)": an option and its default, in one
#: parenthesis or right after it.
DEFAULT_RE = re.compile(
    r"`--(?P<opt>[a-z][a-z-]*)`[ ,]*\(?[^()`]{0,30}?\bdefault:? (?P<v>[`'\"]?[\d.][^\s,;)]*|`[^`]+`)"
    r"(?: for pairs folders, (?P<sim>[^\s,;)]+) for simulate folders)?")


def _options() -> dict[str, list[click.Option]]:
    out: dict[str, list[click.Option]] = {}
    ctx = click.Context(cli)
    for name in cli.list_commands(ctx):
        cmd = cli.get_command(ctx, name)
        for p in cmd.params:
            if isinstance(p, click.Option):
                for name in (*p.opts, *p.secondary_opts):
                    out.setdefault(name, []).append(p)
    return out


def _same(doc: str, value: object) -> bool:
    try:
        return float(doc) == float(value)  # "3" and 3.0
    except (TypeError, ValueError):
        return doc.strip("`'\"") == str(value)


def _documented_defaults():
    for path in DOCS:
        text = " ".join(path.read_text().split())
        for m in DEFAULT_RE.finditer(text):
            yield path.name, m


def test_the_docs_quote_option_defaults():
    found = list(_documented_defaults())
    assert len(found) >= 4  # the pattern still finds the docs' defaults
    opts = _options()
    for doc, m in found:
        name = f"--{m['opt']}"
        assert name in opts, f"{doc}: {name} is not an option of any command"
        pairs, sim = m["v"], m["sim"] or m["v"]
        ok = False
        for p in opts[name]:
            if p.default is not None:
                ok |= _same(pairs, p.default) and _same(sim, p.default)
            elif p.name in PAIRS_LAYOUT:
                ok |= _same(pairs, PAIRS_LAYOUT[p.name]) and (
                    _same(sim, SIMULATION_LAYOUT[p.name])
                    or (SIMULATION_LAYOUT[p.name] is None and sim == "quantile"))
        assert ok, f"{doc}: {m.group(0)!r} disagrees with the command line's default"


# The tutorial's scores against a run: tests/test_defaults.py::
# test_train_with_no_options_beats_the_quality_floor, which runs the tutorial once for
# both checks (the self-tuned default costs about a minute of CPU per run).
