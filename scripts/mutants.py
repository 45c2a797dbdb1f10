#!/usr/bin/env python
"""Targeted mutation run: does the test suite notice a broken core? (issue 30)

Each mutant is one small edit (an operator swapped, a constant changed, a
check removed) to the classifier, the level lookup, the table reader, the
defaults or S-CIELAB's published constants. The script exports the committed
tree (``git archive HEAD``) into a temporary folder, applies one mutant at a
time there, runs the tests named for it (``pytest -x``), and puts the file back
(bytes and modification time) before the next; the working tree is never
touched. A mutant is *killed* when its tests fail, *survived* when they pass.

Usage::

    .venv/bin/python scripts/mutants.py [--only NAME ...] [--json OUT.json] [--keep DIR]

Kernel mutants make numba compile the tile kernel again (about a minute
each on a 2-core machine); the others take seconds. The summary of the last
run and what each survivor means is in ``tests/README.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CLASSIFY_TESTS = ("tests/classify/test_level_cuts_exact.py", "tests/classify/test_classify.py")
TABLE_TESTS = ("tests/test_table.py", "tests/io/test_bad_values.py", "tests/cli/test_bad_input_cli.py")
DEFAULT_TESTS = ("tests/test_defaults.py", "-m", "not slow")


@dataclass(frozen=True)
class Mutant:
    """One edit: ``old`` (found exactly ``count`` times) becomes ``new`` in ``path``."""

    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]
    count: int = 1


MUTANTS = [
    # --- the classifier (tile kernel) and its level lookup
    Mutant("kernel-level-cut-lt", "l3cli/classify/kernel.py",
           "np.int32(cuts[kb, 0] <= lv) + np.int32(cuts[kb, 1] <= lv)",
           "np.int32(cuts[kb, 0] < lv) + np.int32(cuts[kb, 1] < lv)", CLASSIFY_TESTS),
    Mutant("kernel-second-cut-lt", "l3cli/classify/kernel.py",
           "np.int32(cuts[kb, 1] <= lv)", "np.int32(cuts[kb, 1] < lv)", CLASSIFY_TESTS),
    Mutant("kernel-contrast-cut-gt", "l3cli/classify/kernel.py",
           "clsr[x] += np.int32(spr[x] >= ccr[x])", "clsr[x] += np.int32(spr[x] > ccr[x])",
           CLASSIFY_TESTS),
    Mutant("kernel-bucket-clip", "l3cli/classify/kernel.py",
           "kbr[x] = min(max(kb, 0), nlut - 1)", "kbr[x] = min(max(kb, 1), nlut - 1)", CLASSIFY_TESTS),
    Mutant("levels-lut-side", "l3cli/classify/levels.py",
           'np.arange(size) + base, side="left")', 'np.arange(size) + base, side="right")',
           CLASSIFY_TESTS),
    Mutant("levels-two-per-bucket", "l3cli/classify/levels.py",
           "return_counts=True)[1].max() <= 2", "return_counts=True)[1].max() <= 3", CLASSIFY_TESTS),
    Mutant("levels-one-cut-mean", "l3cli/classify/levels.py",
           'np.sqrt(lo * hi) if spacing == "log"', '0.5 * (lo + hi) if spacing == "log"',
           CLASSIFY_TESTS),
    Mutant("levels-linear-is-log", "l3cli/classify/levels.py",
           "return np.linspace(lo, hi, n_cuts)", "return np.geomspace(lo, hi, n_cuts)", CLASSIFY_TESTS),
    # --- the table reader
    Mutant("table-no-version-check", "l3cli/table.py",
           "if version != TABLE_VERSION:", "if False:", TABLE_TESTS),
    Mutant("table-no-format-check", "l3cli/table.py",
           "if fmt.dtype.kind != \"U\" or str(fmt) != TABLE_FORMAT:", "if fmt.dtype.kind != \"U\":",
           TABLE_TESTS),
    Mutant("table-no-missing-keys", "l3cli/table.py",
           "missing = [k for k in _KEYS if k not in arrs]", "missing = []", TABLE_TESTS),
    Mutant("table-no-dtype-check", "l3cli/table.py",
           "ok = dk == kind or (kind == \"i\" and dk == \"u\") or (kind == \"f\" and dk == \"f\")",
           "ok = True", TABLE_TESTS),
    Mutant("table-scalar-shape", "l3cli/table.py", "if a.ndim != 0:", "if a.ndim > 1:", TABLE_TESTS),
    Mutant("table-tone-pair", "l3cli/table.py",
           'if ("tone_lut" in arrs) != ("tone_range" in arrs):', "if False:", TABLE_TESTS),
    Mutant("table-tone-range-empty", "l3cli/table.py",
           "and np.all(rng[1] > rng[0])", "and np.all(rng[1] >= rng[0])", TABLE_TESTS),
    Mutant("table-source-class-bound", "l3cli/table.py",
           "(self.source_class >= nc)", "(self.source_class > nc)", TABLE_TESTS),
    Mutant("table-pickle", "l3cli/table.py",
           "np.load(path, allow_pickle=False)", "np.load(path, allow_pickle=True)", TABLE_TESTS),
    # --- the defaults
    Mutant("pairs-tone-curve-off", "l3cli/defaults.py",
           '"target_space": "linear-srgb", "tone_curve": True,',
           '"target_space": "linear-srgb", "tone_curve": False,', DEFAULT_TESTS),
    Mutant("pairs-tone-curve-off-floor", "l3cli/defaults.py",
           '"target_space": "linear-srgb", "tone_curve": True,',
           '"target_space": "linear-srgb", "tone_curve": False,',
           ("tests/test_defaults.py", "-k", "quality_floor")),
    Mutant("pairs-patch-5", "l3cli/defaults.py", 'PAIRS_LAYOUT = {"patch": 7,', 'PAIRS_LAYOUT = {"patch": 5,',
           DEFAULT_TESTS),
    Mutant("pairs-threshold", "l3cli/defaults.py", '"contrast_threshold": 0.2,', '"contrast_threshold": 0.3,',
           DEFAULT_TESTS),
    Mutant("levels-23", "l3cli/defaults.py", 'SIMULATION_LAYOUT = {"patch": 5, "levels": 24,',
           'SIMULATION_LAYOUT = {"patch": 5, "levels": 23,', DEFAULT_TESTS),
    Mutant("saturation", "l3cli/defaults.py", "SATURATION = 0.95", "SATURATION = 0.9", DEFAULT_TESTS),
    Mutant("min-samples", "l3cli/defaults.py", "MIN_SAMPLES_FACTOR = 3.0", "MIN_SAMPLES_FACTOR = 2.0",
           DEFAULT_TESTS),
    Mutant("merge-positions", "l3cli/defaults.py", "MERGE_POSITIONS = True", "MERGE_POSITIONS = False",
           DEFAULT_TESTS),
    Mutant("spacing-linear", "l3cli/defaults.py", 'LEVEL_SPACING = "log"', 'LEVEL_SPACING = "linear"',
           DEFAULT_TESTS),
    Mutant("dpi", "l3cli/defaults.py", "DPI = 96.0", "DPI = 72.0", DEFAULT_TESTS),
    Mutant("opponent-xyz2", "l3cli/defaults.py", 'SCIELAB_OPPONENT = "xyz10"', 'SCIELAB_OPPONENT = "xyz2"',
           DEFAULT_TESTS),
    Mutant("weight-exponent", "l3cli/defaults.py", "WEIGHT_EXPONENT = 1.5", "WEIGHT_EXPONENT = 1.0",
           DEFAULT_TESTS),
    # --- S-CIELAB's published constants
    Mutant("xyz2-sign", "l3cli/metrics/scielab.py", "[-448.7736, 289.8056, 77.1569]",
           "[-448.7736, 289.8056, -77.1569]", ("tests/metrics/test_scielab.py",)),
    Mutant("xyz10-sign", "l3cli/metrics/scielab.py", "[79.8787, -554.7976, 481.4746]",
           "[79.8787, 554.7976, 481.4746]", ("tests/metrics/test_scielab.py",)),
    Mutant("filter-weight", "l3cli/metrics/scielab.py", "((0.0685, 0.616725), (0.826, 0.383275))",
           "((0.0685, 0.616725), (0.826, 0.283275))", ("tests/metrics/test_scielab.py",)),
    Mutant("filter-spread", "l3cli/metrics/scielab.py", "((0.0920, 0.567885), (0.6451, 0.432115))",
           "((0.0920, 0.567885), (0.6541, 0.432115))", ("tests/metrics/test_scielab.py",)),
    Mutant("original-weight", "l3cli/metrics/scielab.py", "((0.0392, 0.531), (0.494, 0.33))",
           "((0.0392, 0.531), (0.494, 0.38))", ("tests/metrics/test_scielab.py",)),
]


def export_tree(dest: Path) -> None:
    """The committed tree (HEAD) into ``dest``: tracked files only, no .git."""
    archive = subprocess.run(["git", "archive", "--format=tar", "HEAD"], cwd=ROOT, check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)


def run_mutant(tree: Path, m: Mutant, timeout: float, env: dict) -> tuple[str, float, str]:
    """Apply ``m`` in ``tree``, run its tests, restore the file. Returns (status, seconds, last line)."""
    path = tree / m.path
    original = path.read_bytes()
    stat = path.stat()
    text = original.decode()
    found = text.count(m.old) if m.old else -1
    if found != m.count:
        return f"not applied ({found} matches)", 0.0, ""
    try:
        if m.old:
            path.write_text(text.replace(m.old, m.new))
        cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:xdist", "-p", "no:cacheprovider",
               "-p", "no:randomly", *m.tests]
        t0 = time.perf_counter()
        try:
            res = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout)
            status = "survived" if res.returncode == 0 else (
                "killed" if res.returncode == 1 else f"error (rc {res.returncode})")
            tail = [line for line in res.stdout.splitlines() if line.strip()][-1:] or [""]
        except subprocess.TimeoutExpired:
            status, tail = "timeout", [""]
        return status, time.perf_counter() - t0, tail[0]
    finally:
        path.write_bytes(original)
        os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="run only these mutants (names)")
    ap.add_argument("--json", type=Path, help="write the results as JSON")
    ap.add_argument("--keep", type=Path, help="use (and keep) this folder for the exported tree")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per mutant")
    args = ap.parse_args(argv)
    chosen = [m for m in MUTANTS if not args.only or m.name in args.only]
    with tempfile.TemporaryDirectory(prefix="l3-mutants-") as tmp:
        tree = args.keep or Path(tmp) / "tree"
        if not (tree / "l3cli").exists():
            tree.mkdir(parents=True, exist_ok=True)
            export_tree(tree)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(tree / ".numba-cache"), PYTHONDONTWRITEBYTECODE="1")
        env.pop("PYTHONPATH", None)
        results = []
        for tests in dict.fromkeys(m.tests for m in chosen):  # the unmutated tree must pass
            base = Mutant("(none)", chosen[0].path, "", "", tests, count=-1)
            status, secs, tail = run_mutant(tree, base, args.timeout, env)
            print(f"{'baseline':28s} {status:10s} {secs:6.1f} s  {' '.join(tests)}: {tail}", flush=True)
            if status != "survived":
                print("the unmutated tree fails these tests; no mutant can be judged by them")
                return 2
        for m in chosen:
            status, secs, tail = run_mutant(tree, m, args.timeout, env)
            results.append({"name": m.name, "path": m.path, "status": status, "seconds": round(secs, 1),
                            "tests": " ".join(m.tests), "last_line": tail})
            print(f"{m.name:28s} {status:10s} {secs:6.1f} s  {tail}", flush=True)
    killed = sum(r["status"] == "killed" for r in results)
    print(f"{killed} of {len(results)} mutants killed")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0 if killed == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
