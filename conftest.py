"""pytest's collection at the repository root: the docstring examples of ``l3cli/``
run with ``--doctest-modules`` (``pyproject.toml``); the ``export`` package's need
its optional extra (``pip install l3cli[export]``: onnx, onnxruntime) and are left
out where it is absent."""

import importlib.util

collect_ignore_glob = []
if importlib.util.find_spec("onnx") is None or importlib.util.find_spec("onnxruntime") is None:
    collect_ignore_glob.append("l3cli/export/*")
