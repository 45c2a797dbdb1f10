"""The multi-scale stage: the table feature that reduces noise beyond the patch.

One package per table feature, each of the same shape (docs/architecture.md,
"Table features"):

* the model: :mod:`l3cli.multiscale.stage` (the table's ``multiscale`` group,
  :class:`~l3cli.multiscale.stage.Multiscale`, to and from the table's arrays
  with its rule; applied to a float render by
  :func:`~l3cli.multiscale.stage.apply_stage`, or display-encoded by
  :func:`~l3cli.multiscale.stage.apply_display`);
* its compiled loops: :mod:`l3cli.multiscale._loops` (private);
* the fit: :mod:`l3cli.multiscale.fit` (mergeable per-class statistics, solved
  per class) and :mod:`l3cli.multiscale.cv` (the stage's cross-validation for
  self-tuning);
* the export: :mod:`l3cli.export.multiscale` (the stage as ONNX nodes).
"""
