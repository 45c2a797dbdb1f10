"""Lens shading: the table feature that corrects a lens's fall-off, and a DNG's GainMaps.

One package per table feature, each of the same shape (docs/architecture.md,
"Table features"):

* the model: :mod:`l3cli.lens.field` (the table's ``shading`` group: the radial
  :class:`~l3cli.lens.field.GainField`, to and from the table's arrays with its
  rule, applied to a mosaic by :func:`~l3cli.lens.field.correct_mosaic`) and
  :mod:`l3cli.lens.grid` (the spline-grid :class:`~l3cli.lens.grid.SplineField`);
* per raw: :mod:`l3cli.lens.gainmaps` (a DNG's GainMap opcodes, the field and
  the white balance as the gains the tile kernel folds into its band copy);
* the fit: :mod:`l3cli.lens.fit` (a field from blocks' statistics, the model
  chosen by held-out blocks) and :mod:`l3cli.lens.train` (``l3 train``'s step,
  from the training pairs);
* the export: :func:`l3cli.export.stages.shading` (the field as ONNX nodes).
"""
