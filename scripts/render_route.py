"""Follow one render of a raw to JPEG through l3's modules (the "render route").

Usage::

    .venv/bin/python scripts/render_route.py TABLE.npz RAW [--show] [--functions]

Traces (``sys.setprofile``, this thread only) the per-file render that
``l3 render RAW -o out.jpg`` runs, from :func:`l3cli.pipeline.render_one`'s entry
to its return, and prints the route: the l3cli modules control passes
through, consecutive calls in one module merged, property getters (``table.cfa``)
not counted as calls. Counted:

* *stops*: entries of the route (a move from one module to another, by a call
  or a return, is one stop);
* *modules*: distinct modules on the route;
* *returns to a module already left*: stops at a module the route had
  already passed through and left (a climb back up the call tree, or a
  second visit).

The file's read and the output's write (``l3cli.io`` but the display
encoder, ``l3cli.startup``) and modules of the standard library or third
parties are left out: the route is l3's own code between them.
"""

from __future__ import annotations

import functools
import sys
import tempfile
from pathlib import Path

#: The read and write stages (files, signals), not followed.
SKIP = ("l3cli.io.", "l3cli.startup")


class _Given:
    """A prefetch that hands over a raw already read (the read stays out of the route)."""

    def __init__(self, raw) -> None:
        self.raw = raw

    def take(self, path):
        raw, self.raw = self.raw, None
        return raw


def _attribute(frame) -> bool:
    """True for a property's getter (``table.cfa``): reading an attribute, not a stop."""
    obj = frame.f_locals.get("self")
    if obj is None:
        return False
    attr = getattr(type(obj), frame.f_code.co_name, None)
    return isinstance(attr, property | functools.cached_property)


def route_of(table_path: str, raw_path: str) -> list[str]:
    from l3cli.io.raw import read_raw
    from l3cli.pipeline import render_one, warm_up
    from l3cli.table import load_table

    table = load_table(table_path)
    raw = read_raw(raw_path)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.jpg"
        warm_up(table, out)
        render_one(table, "t", raw_path, out, {}, prefetch=_Given(raw))  # first calls: untraced
        raw = read_raw(raw_path)
        route: list[str] = []
        names: list[str] = []  # the function each stop is in

        def where(frame) -> str | None:
            name = frame.f_globals.get("__name__", "")
            return name if name.startswith("l3cli") else None

        def prof(frame, event, arg):
            if event not in ("call", "return") or _attribute(frame):
                return
            mod = where(frame)
            if event == "return":  # back in the caller's module
                frame = frame.f_back
                mod = where(frame) if frame is not None else None
            if mod is None or (mod.startswith(SKIP) and mod != "l3cli.io.encode"):
                return
            if not route or route[-1] != mod:
                route.append(mod)
                names.append(frame.f_code.co_name)

        sys.setprofile(prof)
        try:
            render_one(table, "t", raw_path, out, {}, prefetch=_Given(raw))
        finally:
            sys.setprofile(None)
    return [f"{m}:{n}" for m, n in zip(route, names, strict=True)]


def main(argv: list[str]) -> None:
    if len(argv) < 2:
        sys.exit(__doc__)
    stops = route_of(argv[0], argv[1])
    route = [s.partition(":")[0] for s in stops]
    seen: set[str] = set()
    back = 0
    for mod in route:
        if mod in seen:
            back += 1
        seen.add(mod)
    if "--show" in argv:
        print(" -> ".join(m.removeprefix("l3cli.") for m in route))
    if "--functions" in argv:
        print("\n".join(s.removeprefix("l3cli.") for s in stops))
    print(f"stops {len(route)}, modules {len(seen)}, returns to a module already left {back}")


if __name__ == "__main__":
    main(sys.argv[1:])
