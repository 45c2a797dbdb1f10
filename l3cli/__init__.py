"""l3: learn a camera's image-processing pipeline with Local, Linear, Learned transforms.

The package is a library core (``l3cli.*``) with a thin click command line in
:mod:`l3cli.cli`. See ``docs/`` for the tutorial and file formats.

The top-level API (README, "From Python"), imported on first use so that
``import l3cli`` stays light (``l3 render``'s start-up):

* ``l3cli.train(inputs, **options)``: what ``l3 train`` does
  (:func:`l3cli.train.api.train`; the package :mod:`l3cli.train` is callable);
* ``l3cli.load_table(path)``: a table that renders, ``.render(raw)``
  (:class:`l3cli.model.Table`);
* ``l3cli.evaluate(image, reference)``: the metrics of ``l3 evaluate`` for one
  image (:func:`l3cli.evaluate.metrics.evaluate_images`; the package
  :mod:`l3cli.evaluate` is callable).
"""

__version__ = "0.1.0"

__all__ = ["__version__", "train", "load_table", "evaluate", "Table"]

#: The top-level names and the modules that hold them (imported on first use, by
#: name: this package sits below every layer, tests/test_layering.py).
_LAZY = {"train": "l3cli.train", "evaluate": "l3cli.evaluate", "load_table": "l3cli.model",
         "Table": "l3cli.model"}


def __getattr__(name: str):
    where = _LAZY.get(name)
    if where is None:
        raise AttributeError(f"module 'l3cli' has no attribute {name!r}")
    import importlib

    module = importlib.import_module(where)
    return module if where == f"l3cli.{name}" else getattr(module, name)


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
