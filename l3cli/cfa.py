"""Colour filter array (CFA) model.

A CFA is any rectangular repeating pattern of named channels. l3 knows the
channel names below; the pattern is given as a string (``"RGGB"``,
``"GRBG"``, ``"RGBW/WRGB..."``) or as a 2-D list of names
(``[["R", "G"], ["NIR", "B"]]``).

Notation (see ``docs/conventions.md``): the pattern is written row by row from
the top-left pixel of the image; position ``p = (y % ph) * pw + (x % pw)`` is
the pixel's place in the repeat of period ``(ph, pw)``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from l3cli.errors import ConfigError

__all__ = ["CFA", "KNOWN_CHANNELS", "DNG_CFA_CODES"]

#: Channel names l3 accepts, with what they mean.
KNOWN_CHANNELS: dict[str, str] = {
    "R": "red",
    "G": "green",
    "B": "blue",
    "W": "white / clear (panchromatic)",
    "C": "cyan",
    "M": "magenta",
    "Y": "yellow",
    "E": "emerald",
    "NIR": "near infrared",
}

#: DNG CFAPattern colour codes (TIFF/EP); channels outside this map (W, NIR)
#: cannot be described by a DNG file.
DNG_CFA_CODES: dict[str, int] = {"R": 0, "G": 1, "B": 2, "C": 3, "M": 4, "Y": 5}

_TOKEN = re.compile(r"NIR|IR|[A-Z]")
_ALIASES = {"IR": "NIR"}


def _tokenize_row(row: str, spec: object) -> list[str]:
    row = row.strip().upper()
    if re.search(r"[\s,]", row):
        toks = [t for t in re.split(r"[\s,]+", row) if t]
    else:
        toks = []
        pos = 0
        while pos < len(row):
            m = _TOKEN.match(row, pos)
            if m is None:
                raise ConfigError(
                    f"CFA {spec!r}: cannot read {row[pos:]!r}; channels are "
                    f"{', '.join(KNOWN_CHANNELS)}"
                )
            toks.append(m.group(0))
            pos = m.end()
    return [_ALIASES.get(t, t) for t in toks]


@dataclass(frozen=True)
class CFA:
    """A rectangular repeating colour filter array.

    Parameters
    ----------
    pattern
        Rows of channel names; every row has the same length.

    Examples
    --------
    >>> cfa = CFA.from_spec("GRBG")
    >>> cfa.period
    (2, 2)
    >>> cfa.channels
    ('G', 'R', 'B')
    >>> cfa.channel_at(0, 1)
    'R'
    """

    pattern: tuple[tuple[str, ...], ...]

    def __post_init__(self) -> None:
        if not self.pattern or not self.pattern[0]:
            raise ConfigError("CFA: the pattern is empty")
        widths = {len(r) for r in self.pattern}
        if len(widths) != 1:
            raise ConfigError(f"CFA {self.spec!r}: rows have different lengths {sorted(widths)}")
        for row in self.pattern:
            for name in row:
                if name not in KNOWN_CHANNELS:
                    raise ConfigError(
                        f"CFA {self.spec!r}: unknown channel {name!r}; allowed: "
                        f"{', '.join(KNOWN_CHANNELS)}"
                    )

    # ------------------------------------------------------------------ parsing
    @classmethod
    def from_spec(cls, spec: str | Sequence[Sequence[str]] | CFA) -> CFA:
        """Build a CFA from a string or a 2-D list of channel names.

        Strings: ``"RGGB"`` (4 letters → 2x2, 16 → 4x4, any square count),
        rows separated by ``/`` or ``;`` for non-square patterns
        (``"RGB/GBR"``), channels separated by spaces or commas where names
        have several letters (``"R G / NIR B"``).
        """
        if isinstance(spec, CFA):
            return spec
        if isinstance(spec, str):
            text = spec.strip()
            if not text:
                raise ConfigError("CFA: the pattern is empty")
            if re.search(r"[/;]", text):
                rows = [_tokenize_row(r, spec) for r in re.split(r"[/;]", text) if r.strip()]
            else:
                toks = _tokenize_row(text, spec)
                n = len(toks)
                side = math.isqrt(n)
                if side * side != n:
                    raise ConfigError(
                        f"CFA {spec!r}: {n} channels is not a square pattern; write rows "
                        "separated by '/' (e.g. 'RGB/GBR') or give a 2-D list"
                    )
                rows = [toks[i * side : (i + 1) * side] for i in range(side)]
            return cls(tuple(tuple(r) for r in rows))
        try:
            rows = [
                [_ALIASES.get(str(c).strip().upper(), str(c).strip().upper()) for c in row]
                for row in spec
            ]
        except TypeError as exc:
            raise ConfigError(f"CFA {spec!r}: expected a string or a 2-D list of names") from exc
        if any(isinstance(row, str) for row in spec):
            # a list of row strings like ["RG", "GB"]
            rows = [_tokenize_row(str(row), spec) for row in spec]
        return cls(tuple(tuple(r) for r in rows))

    # --------------------------------------------------------------- properties
    @property
    def spec(self) -> str:
        """Canonical text form: rows joined by '/', names by spaces where needed."""
        multi = any(len(c) > 1 for row in self.pattern for c in row)
        sep = " " if multi else ""
        return "/".join(sep.join(row) for row in self.pattern)

    def __str__(self) -> str:
        return self.spec

    @property
    def period(self) -> tuple[int, int]:
        """(rows, columns) of the repeat."""
        return len(self.pattern), len(self.pattern[0])

    @property
    def n_positions(self) -> int:
        """Number of positions in the repeat."""
        ph, pw = self.period
        return ph * pw

    @cached_property
    def channels(self) -> tuple[str, ...]:
        """Distinct channel names in order of first appearance (row major)."""
        seen: list[str] = []
        for row in self.pattern:
            for c in row:
                if c not in seen:
                    seen.append(c)
        return tuple(seen)

    @property
    def n_channels(self) -> int:
        """Number of distinct channels."""
        return len(self.channels)

    @cached_property
    def index_pattern(self) -> np.ndarray:
        """(ph, pw) int array: channel index of each position in the repeat."""
        lut = {c: i for i, c in enumerate(self.channels)}
        return np.array([[lut[c] for c in row] for row in self.pattern], dtype=np.int64)

    def channel_at(self, y: int, x: int) -> str:
        """Channel name of image pixel (y, x)."""
        ph, pw = self.period
        return self.pattern[y % ph][x % pw]

    def position_at(self, y: int, x: int) -> int:
        """Position-in-repeat index of image pixel (y, x)."""
        ph, pw = self.period
        return (y % ph) * pw + (x % pw)

    def position_map(self, height: int, width: int) -> np.ndarray:
        """(H, W) int32 array of position-in-repeat indices."""
        ph, pw = self.period
        yy = (np.arange(height) % ph)[:, None]
        xx = (np.arange(width) % pw)[None, :]
        return (yy * pw + xx).astype(np.int32)

    def channel_map(self, height: int, width: int) -> np.ndarray:
        """(H, W) int32 array of channel indices into :attr:`channels`."""
        ph, pw = self.period
        reps = (-(-height // ph), -(-width // pw))
        return np.tile(self.index_pattern, reps)[:height, :width].astype(np.int32)

    def masks(self, height: int, width: int) -> np.ndarray:
        """(C, H, W) boolean masks, one per channel."""
        cmap = self.channel_map(height, width)
        return np.stack([cmap == i for i in range(self.n_channels)])

    def neighbourhood(self, position: int, size: int) -> np.ndarray:
        """(size, size) channel indices of the patch centred on ``position``.

        Examples
        --------
        >>> cfa = CFA.from_spec("RGGB")  # channels R=0, G=1, B=2
        >>> cfa.neighbourhood(0, 3).tolist()  # a 3x3 patch centred on R
        [[2, 1, 2], [1, 0, 1], [2, 1, 2]]
        """
        if size < 1 or size % 2 == 0:
            raise ConfigError(f"patch size {size} is not allowed; use an odd size >= 1")
        ph, pw = self.period
        cy, cx = divmod(position, pw)
        r = size // 2
        ys = (cy + np.arange(-r, r + 1)) % ph
        xs = (cx + np.arange(-r, r + 1)) % pw
        return self.index_pattern[np.ix_(ys, xs)]

    def equivalent_positions(self, size: int) -> list[list[int]]:
        """Groups of positions whose ``size`` x ``size`` neighbourhood layouts coincide.

        Examples
        --------
        In a Bayer CFA every position sees its own layout:

        >>> CFA.from_spec("RGGB").equivalent_positions(5)
        [[0], [1], [2], [3]]

        Nor in this 4x4 RGBW CFA (each of its 16 positions has its own 5x5 layout):

        >>> len(CFA.from_spec("RGBW/GWRB/BRWG/WBGR").equivalent_positions(5))
        16
        """
        groups: dict[bytes, list[int]] = {}
        for p in range(self.n_positions):
            key = self.neighbourhood(p, size).tobytes()
            groups.setdefault(key, []).append(p)
        return list(groups.values())

    # ---------------------------------------------------------- transformations
    def shifted(self, dy: int, dx: int) -> CFA:
        """The CFA of the image cropped by ``dy`` rows and ``dx`` columns at the top-left.

        Examples
        --------
        >>> CFA.from_spec("RGGB").shifted(0, 1).spec
        'GR/BG'
        >>> CFA.from_spec("RGGB").shifted(1, 1).spec
        'BG/GR'
        """
        ph, pw = self.period
        rows = [
            tuple(self.pattern[(y + dy) % ph][(x + dx) % pw] for x in range(pw))
            for y in range(ph)
        ]
        return CFA(tuple(rows))

    def flipped(self, *, horizontal: bool = False, vertical: bool = False, width: int = 0,
                height: int = 0) -> CFA:
        """The CFA of the image mirrored left-right and/or up-down.

        ``width``/``height`` are the image size (the phase of the mirrored
        pattern depends on it).
        """
        ph, pw = self.period
        rows = []
        for y in range(ph):
            yy = (height - 1 - y) if vertical else y
            rows.append(
                tuple(self.pattern[yy % ph][((width - 1 - x) if horizontal else x) % pw]
                      for x in range(pw))
            )
        return CFA(tuple(rows))

    def dng_codes(self) -> list[int] | None:
        """DNG CFAPattern codes, or ``None`` when a channel has no DNG code."""
        try:
            return [DNG_CFA_CODES[c] for row in self.pattern for c in row]
        except KeyError:
            return None

    def to_list(self) -> list[list[str]]:
        """The pattern as a 2-D list of names (for TOML/JSON)."""
        return [list(r) for r in self.pattern]
