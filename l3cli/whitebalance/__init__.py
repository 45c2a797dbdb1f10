"""White balance as an input: the table feature that renders every shot's white.

One package per table feature, each of the same shape (docs/architecture.md,
"Table features"):

* the model: :mod:`l3cli.whitebalance.model` (the as-shot gains normalise the
  mosaic; :class:`~l3cli.whitebalance.model.WhiteBalanceModel`, the table's
  ``white_balance`` group, adapts the colour per shot);
* the fit: :mod:`l3cli.whitebalance.fit` (the adaptation model of the training
  shots);
* the export: the gains and the adaptation in :mod:`l3cli.export.stages`.
"""
