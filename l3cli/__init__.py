"""l3: learn a camera's image-processing pipeline with Local, Linear, Learned transforms.

The package is a library core (``l3cli.*``) with a thin click command line in
:mod:`l3cli.cli`. See ``docs/`` for the tutorial and file formats.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
