"""The numbers the user docs quote, made by running the commands they show.

    python scripts/docs_numbers.py            # run the tutorial, rewrite the blocks
    python scripts/docs_numbers.py --check    # run it, fail if the docs disagree

The real-camera tutorial (docs/real-camera.md, `scripts/real_camera.sh` on the
bundled `examples/infinite_isp/`) is run with `l3 train`'s defaults into a
temporary folder; its scores replace the text between the markers
``<!-- numbers:real-camera-tutorial -->`` and ``<!-- /numbers -->``.
``tests/test_defaults.py::test_train_with_no_options_beats_the_quality_floor`` runs the check (marked slow), so a change that
moves the tutorial's results fails until the docs are regenerated.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "real-camera.md"
BEGIN, END = "<!-- numbers:real-camera-tutorial -->", "<!-- /numbers -->"
#: Allowed difference when checking: scores move with BLAS and numba builds
#: only in the last digits; a change of method moves them by more.
TOLERANCE = {"scielab": 0.01, "chart": 0.05}


def _children_cpu() -> float:
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def run_tutorial(l3: str, out: Path) -> dict:
    """Run scripts/real_camera.sh on the bundled set; its numbers."""
    env = {**os.environ, "L3_TRAIN_OPTS": ""}
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    proc = subprocess.run(["bash", str(REPO / "scripts" / "real_camera.sh"), l3, str(out)],
                          capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    cpu = _children_cpu() - cpu0
    if proc.returncode != 0:
        raise SystemExit(f"real_camera.sh failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    found = re.search(r"trained from (\d+) captures \((\d+) samples\)", proc.stdout + proc.stderr)
    images = {}
    for p in sorted(out.glob("eval_*.json")):
        for im in json.loads(p.read_text())["images"]:
            images[Path(im["name"]).stem.removesuffix("_crop")] = {
                "scielab": round(im["scielab_mean"], 3), "chart": round(im["macbeth_de_mean"], 2)}
    return {"seconds": round(seconds), "cpu_seconds": round(cpu), "samples": int(found.group(2)) if found else None,
            "images": images}


def block(numbers: dict) -> str:
    """The Markdown between the markers."""
    names = sorted(numbers["images"])
    sc = " and ".join(f"{numbers['images'][n]['scielab']:.3f}" for n in names)
    ch = " and ".join(f"{numbers['images'][n]['chart']:.2f}" for n in names)
    samples = numbers["samples"]
    return (f"{BEGIN}\n"
            f"With `l3 train`'s defaults it gives, on {' and '.join(names)}: holdout S-CIELAB "
            f"ΔE*ab {sc}, ColorChecker ΔE*ab {ch}, trained on "
            f"{samples / 1e6:.1f} M samples; the whole script took {numbers['cpu_seconds']} s "
            f"of CPU (`python scripts/docs_numbers.py` re-runs it and rewrites these numbers; "
            "a test checks them). These score the crops, so they are not comparable with the "
            "full-frame numbers below.\n"
            f"{END}")


def parse(text: str) -> dict:
    """The numbers in the docs' block (the inverse of :func:`block`, for ``--check``)."""
    m = re.search(re.escape(BEGIN) + r"(.*?)" + re.escape(END), text, re.S)
    if m is None:
        raise SystemExit(f"{DOC}: no {BEGIN} block")
    body = " ".join(m.group(1).split())
    names = re.search(r"on (.+?): holdout", body).group(1).split(" and ")
    sc = re.search(r"S-CIELAB ΔE\*ab ([\d. and]+?), ColorChecker", body).group(1).split(" and ")
    ch = re.search(r"ColorChecker ΔE\*ab ([\d. and]+?), trained", body).group(1).split(" and ")
    return {"images": {n: {"scielab": float(s), "chart": float(c)}
                       for n, s, c in zip(names, sc, ch, strict=True)}}


def check(numbers: dict, text: str) -> list[str]:
    """Where the docs disagree with a run (empty: they agree)."""
    doc = parse(text)["images"]
    bad = []
    if set(doc) != set(numbers["images"]):
        return [f"images {sorted(doc)} in the docs, {sorted(numbers['images'])} in the run"]
    for name, got in numbers["images"].items():
        for key, tol in TOLERANCE.items():
            if abs(got[key] - doc[name][key]) > tol:
                bad.append(f"{name} {key}: docs {doc[name][key]}, run {got[key]}")
    return bad


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare instead of rewriting")
    ap.add_argument("--l3", default=str(Path(sys.executable).parent / "l3"), help="l3 executable")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="l3-docs-") as tmp:
        numbers = run_tutorial(args.l3, Path(tmp))
    text = DOC.read_text()
    if args.check:
        bad = check(numbers, text)
        for line in bad:
            print(f"{DOC.name}: {line}", file=sys.stderr)
        return 1 if bad else 0
    new = re.sub(re.escape(BEGIN) + r".*?" + re.escape(END), lambda _: block(numbers), text,
                 flags=re.S)
    DOC.write_text(new)
    print(json.dumps(numbers, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
