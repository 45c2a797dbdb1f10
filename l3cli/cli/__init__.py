"""The ``l3`` command line: a thin click layer over the l3cli library core."""
