"""The learned tone curve: the table feature that renders the renders' own linear space.

One package per table feature, each of the same shape (docs/architecture.md,
"Table features"):

* the model: :mod:`l3cli.tone.curve` (the table's curve: per-channel look-up
  tables, chosen among candidate curves, to and from the table's arrays);
* the curve and the display encoding as one look-up per value:
  :mod:`l3cli.tone.code` (used by the tile kernel's display output);
* the fit: :mod:`l3cli.tone.fit` (``l3 train``'s step, from the pairs' flat blocks);
* the export: the curve's look-up in :mod:`l3cli.export.stages`.
"""
