"""numba kernels' machine code, stored once and loaded later without importing numba.

Importing numba and loading a kernel from its cache is most of a short
``l3 render``'s start-up: ~0.35 s to import numba (its typing and lowering of
all of Python and numpy, which only *compiling* needs) and ~0.2 s to load the
render kernel (docs/performance.md). The machine code itself loads in a few
milliseconds: numba's compiled code needs only LLVM's loader (llvmlite), its
runtime's C helpers (numba's ``_nrt_python``, ``_helperlib`` and
``_dynfunc`` extension modules, which import nothing of numba) and the
CPython C API.

:class:`Stored` wraps one ``@njit`` function. A call looks the arguments'
types up (:func:`typekey`, numba's ``typeof`` for the kinds l3 passes) and
runs, in order of preference:

1. the code already loaded in this process;
2. the code stored on disk for this key (:func:`load`): the arguments'
   types, the text of the source modules the code comes from, numba's and
   llvmlite's versions, the CPU and its features, and the ``NUMBA_*``
   settings (anything that changes the machine code numba would make);
3. numba itself (``dispatcher()``: imports numba, loads or compiles as
   always), after which the code is stored for the next process
   (:func:`save`).

Stored code is numba's own object code for that function, the very code its
cache holds, so results are bit for bit those of the numba dispatcher. Any
failure to load (a missing file, another numba, a truncated file) falls
back to numba (a FIFO or any other non-regular file in its place too: opened
non-blocking, never waited on); a failure to store is logged at debug level only.

Where: ``$NUMBA_CACHE_DIR/l3cli-kernels`` when set, else the package's
``__pycache__/kernels`` when writable, else ``$XDG_CACHE_HOME/l3cli/kernels``
(``~/.cache``). A file holds one function's object code for one key, with a
header naming the key and the code's SHA-256 (checked on every load). Code
not loaded for :data:`PRUNE_DAYS` is removed when new code is stored; the
folder may be deleted at any time (the next run compiles again).
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import hashlib
import importlib.util
import json
import logging
import os
import stat
import sys
import tempfile
import threading
import time
import types
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Stored", "in_use", "load", "prepare", "save", "store_dirs", "stored_any",
           "typekey"]

log = logging.getLogger(__name__)

_MAGIC = b"l3cli-kernel 1\n"
#: Stored code not loaded for this many days is removed when code is next stored.
PRUNE_DAYS = 30
#: ``NUMBA_*`` settings that do not change machine code (left out of the key).
_RUNTIME_ONLY = {"NUMBA_NUM_THREADS", "NUMBA_CACHE_DIR", "NUMBA_DEBUG_CACHE",
                 "NUMBA_THREADING_LAYER", "NUMBA_DISABLE_PERFORMANCE_WARNINGS"}
_lock = threading.RLock()
_runtime: dict[str, Any] = {}


def typekey(value: Any) -> str:
    """numba's type of ``value`` as a short string, for the kinds l3 passes to kernels.

    Arrays: dtype, dimensions, layout (``C``, ``F`` or ``A``, as numba's
    ``typeof``), writable and aligned flags. Python ``bool``, ``int`` and
    ``float`` are numba's ``boolean``, ``int64`` and ``float64``; numpy
    scalars their dtype; tuples their items'. Anything else raises
    ``TypeError`` (the caller uses numba's dispatcher).
    """
    if isinstance(value, np.ndarray):
        f = value.flags
        layout = "C" if f.c_contiguous else "F" if f.f_contiguous else "A"
        return (f"a{value.dtype.str}{value.ndim}{layout}{'w' if f.writeable else 'r'}"
                f"{'a' if f.aligned else 'u'}")
    if isinstance(value, (bool, np.bool_)):
        return "b"
    if isinstance(value, int):
        if not -(1 << 63) <= value < (1 << 63):
            raise TypeError("integer out of int64 range")
        return "i8"
    if isinstance(value, float):
        return "f8"
    if isinstance(value, np.generic):
        return value.dtype.str
    if isinstance(value, tuple):
        return "(" + ",".join(typekey(v) for v in value) + ")"
    raise TypeError(f"no stored-kernel type for {type(value).__name__}")


def store_dirs() -> list[Path]:
    """Where stored kernels are looked for, in order (the first writable one is written)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return [Path(os.environ["NUMBA_CACHE_DIR"]) / "l3cli-kernels"]
    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return [Path(__file__).resolve().parent / "__pycache__" / "kernels",
            Path(home) / "l3cli" / "kernels"]


def in_use() -> bool:
    """Whether this process already runs compiled kernels (stored code loaded, or numba
    imported): where one more kernel costs little to load."""
    return "dynfunc" in _runtime or "numba" in sys.modules


def _numba_dir() -> Path | None:
    spec = importlib.util.find_spec("numba")  # a top-level find: imports nothing
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


def _machine_key() -> dict[str, Any]:
    """What the machine code depends on besides l3's sources (cached per process)."""
    with _lock:
        if "machine" not in _runtime:
            import llvmlite
            import llvmlite.binding as llvm

            nbdir = _numba_dir()
            version = (hashlib.sha256((nbdir / "_version.py").read_bytes()).hexdigest()
                       if nbdir is not None else "")
            _runtime["machine"] = {
                "numba": version, "llvmlite": llvmlite.__version__,
                "python": sys.implementation.cache_tag, "triple": llvm.get_process_triple(),
                "cpu": llvm.get_host_cpu_name(),
                "features": llvm.get_host_cpu_features().flatten(),
                "env": sorted((k, v) for k, v in os.environ.items()
                              if k.startswith("NUMBA_") and k not in _RUNTIME_ONLY)}
        return _runtime["machine"]


def _digest(sources: Sequence[str | os.PathLike]) -> str:
    """Digest of the machine and the sources (the part of a key shared by all types)."""
    h = hashlib.sha256()
    h.update(json.dumps(_machine_key(), sort_keys=True).encode())
    for src in sources:
        h.update(Path(src).read_bytes())
    return h.hexdigest()[:16]


def _file(folder: Path, name: str, digest: str, types_: str) -> Path:
    return folder / f"{name}-{digest}-{hashlib.sha256(types_.encode()).hexdigest()[:12]}.bin"


def stored_any(name: str, sources: Sequence[str | os.PathLike]) -> bool:
    """Whether code of kernel ``name`` is stored for these sources and this machine (for
    any argument types)."""
    try:
        digest = _digest(sources)
    except Exception:  # noqa: BLE001 - then nothing is usable
        return False
    return any(glob.glob(str(folder / f"{name}-{digest}-*.bin")) for folder in store_dirs())


def _extension(name: str, rel: str) -> types.ModuleType:
    """numba's C extension module ``name`` (file ``rel`` under numba), loaded on its own
    (:func:`l3cli.startup.extension_module`: a later ``import numba`` uses this one)."""
    from l3cli.startup import extension_module

    nbdir = _numba_dir()
    module = (extension_module(name, nbdir / os.path.dirname(rel)) if nbdir is not None
              else None)
    if module is None:
        raise ImportError(f"numba's {rel} not found")
    return module


def _loader() -> tuple[Any, Any]:
    """llvmlite's binding and numba's ``_dynfunc``, with numba's runtime symbols registered."""
    with _lock:
        if "dynfunc" not in _runtime:
            import llvmlite.binding as llvm

            nrt = _extension("numba.core.runtime._nrt_python", "core/runtime/_nrt_python")
            helper = _extension("numba._helperlib", "_helperlib")
            dynfunc = _extension("numba._dynfunc", "_dynfunc")
            # the names numba's runtime and its helpers are linked under
            for prefix, module in (("NRT_", nrt), ("numba_", helper)):
                for py_name, address in module.c_helpers.items():
                    llvm.add_symbol(py_name if py_name.startswith("_") else prefix + py_name,
                                    address)
            llvm.initialize_native_target()
            llvm.initialize_native_asmprinter()
            _runtime["dynfunc"] = dynfunc
        return sys.modules["llvmlite.binding"], _runtime["dynfunc"]


def prepare() -> None:
    """Do the per-process part of loading now: llvmlite's and numba's runtime libraries,
    the machine's key (for a thread to run while the main thread imports: the
    libraries' loading and llvmlite's calls release the GIL). Never raises."""
    try:
        _machine_key()
        _loader()
    except Exception as exc:  # noqa: BLE001 - load() reports and falls back
        log.debug("kernel store not prepared: %s", exc)


def load(name: str, sources: Sequence[str | os.PathLike], types_: str) -> Callable | None:
    """The stored kernel ``name`` for arguments of types ``types_``, or None.

    ``sources``: the files the kernel's code comes from. None when nothing is
    stored for this key, or anything about the stored code is not as written.
    """
    try:
        digest = _digest(sources)
        for folder in store_dirs():
            path = _file(folder, name, digest, types_)
            try:
                data = _read_regular(path)
            except OSError:
                continue
            fn = _link(path, data, f"{name} {digest} {types_}")
            with contextlib.suppress(OSError):
                os.utime(path)  # in use: not pruned (save())
            return fn
    except Exception as exc:  # noqa: BLE001 - numba is the fallback
        log.debug("stored kernel %s not loaded: %s", name, exc)
    return None


def _read_regular(path: Path) -> bytes:
    """The bytes of a stored file, opened without blocking: a FIFO, a device or a folder
    in its place is refused at once (``ValueError``: as a damaged file, numba is the
    fallback), never waited on."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with open(fd, "rb") as fh:  # closes fd
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError(f"{path}: not a regular file")
        return fh.read()


def _link(path: Path, data: bytes, key: str) -> Callable:
    if not data.startswith(_MAGIC):
        raise ValueError(f"{path}: not a stored kernel")
    end = data.index(b"\n", len(_MAGIC))
    head = json.loads(data[len(_MAGIC):end])
    obj = data[end + 1:]
    if (head.get("digest") != key or len(obj) != head.get("size")
            or hashlib.sha256(obj).hexdigest() != head.get("sha256")):
        raise ValueError(f"{path}: stored for another key, truncated or damaged")
    llvm, dynfunc = _loader()
    with _lock:
        # a target machine per engine: the engine owns it (and disposes of it with itself)
        target = llvm.Target.from_default_triple().create_target_machine()
        engine = llvm.create_mcjit_compiler(llvm.parse_assembly(""), target)
        engine.add_object_file(llvm.ObjectFileRef.from_data(obj))
        engine.finalize_object()
        address = engine.get_function_address(head["wrapper"])
        env_slot = engine.get_global_value_address(head["env"])
    if not address or not env_slot:
        raise ValueError(f"{path}: symbols missing")
    env = dynfunc.Environment({})  # no constants: save() stores only such code
    ctypes.c_void_p.from_address(env_slot).value = id(env)
    module = types.ModuleType(head["module"])
    fn = dynfunc.make_function(module, head["qualname"].rsplit(".", 1)[-1], "", address, env,
                               (engine, env))
    log.debug("%s: stored kernel loaded", path)
    return fn


def save(name: str, sources: Sequence[str | os.PathLike], types_: str, dispatcher: Any,
         args: Sequence[Any]) -> Path | None:
    """Store the machine code ``dispatcher`` (numba, already called with ``args``) runs.

    Returns the file, or None where nothing was stored (code that needs
    Python objects at run time, no writable folder).
    """
    try:
        sig = tuple(dispatcher.typeof_pyval(a) for a in args)
        cres = dispatcher.overloads.get(sig)
        if cres is None or cres.objectmode or cres.environment.consts:
            return None
        _, _, payload = cres.library.serialize_using_object_code()
        obj = payload[0]
        digest = _digest(sources)
        head = {"digest": f"{name} {digest} {types_}", "size": len(obj),
                "sha256": hashlib.sha256(obj).hexdigest(),
                "wrapper": cres.fndesc.llvm_cpython_wrapper_name, "env": cres.fndesc.env_name,
                "module": cres.fndesc.modname, "qualname": cres.fndesc.qualname}
        blob = _MAGIC + json.dumps(head).encode() + b"\n" + obj
    except Exception as exc:  # noqa: BLE001 - an optimisation only
        log.debug("kernel %s not stored: %s", name, exc)
        return None
    for folder in store_dirs():
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".bin")
            try:
                os.chmod(tmp, 0o644)  # readable as numba's cache files are (mkstemp: 0600)
                with os.fdopen(fd, "wb") as f:
                    f.write(blob)
                os.replace(tmp, _file(folder, name, digest, types_))
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
            _prune(folder)
            return _file(folder, name, digest, types_)
        except OSError as exc:
            log.debug("kernel %s not stored in %s: %s", name, folder, exc)
    with _lock:
        if not _runtime.get("warned"):
            _runtime["warned"] = True
            log.warning("compiled kernels cannot be stored (no writable folder among %s): "
                        "every run compiles them again; set NUMBA_CACHE_DIR to a writable "
                        "folder", ", ".join(str(f) for f in store_dirs()))
    return None


@contextlib.contextmanager
def compiling(name: str, sources: Sequence[str | os.PathLike], types_: str):
    """Held while this process compiles kernel ``name`` for ``types_``: an exclusive
    ``flock`` on a lock file in the first writable store folder, so that processes
    starting together (pytest or dask workers, a folder's renders) compile each
    kernel once, the others then loading its stored code. The operating system
    releases the lock of a process that dies; where no folder is writable or
    ``fcntl`` is missing, nothing is held."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    key = hashlib.sha256(f"{name} {_digest(sources)} {types_}".encode()).hexdigest()[:24]
    fd = None
    for folder in store_dirs():
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(folder / f".lock-{key}", os.O_RDWR | os.O_CREAT | os.O_NONBLOCK, 0o644)
            break
        except OSError:
            continue
    if fd is None:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _prune(folder: Path) -> None:
    """Remove stored code not loaded for :data:`PRUNE_DAYS` (older sources, other numbas)."""
    old = time.time() - PRUNE_DAYS * 86400
    for path in [*folder.glob("*.bin"), *folder.glob(".lock-*")]:
        with contextlib.suppress(OSError):
            if path.stat().st_mtime < old:
                path.unlink()


class Stored:
    """An ``@njit`` function served from stored machine code when there is some.

    Parameters
    ----------
    name
        File-name stem of the stored code (unique per compiled variant).
    sources
        The source files the code comes from (the function's module and its
        callees'): any change to them is a new key.
    dispatcher
        Returns the numba dispatcher (imports numba); called only when no
        stored code fits (after :func:`l3cli.startup.preload_scipy_blas`).
    context
        Optional: returns a context manager to hold while numba compiles (its
        compiler settings).
    """

    def __init__(self, name: str, sources: Sequence[str | os.PathLike],
                 dispatcher: Callable[[], Any],
                 context: Callable[[], contextlib.AbstractContextManager] | None = None) -> None:
        self.name = name
        self.sources = [str(s) for s in sources]
        self._dispatcher = dispatcher
        self._context = context or contextlib.nullcontext
        self._fns: dict[str, Callable] = {}
        self._lock = threading.Lock()

    def function(self, *args: Any, compile: bool = True) -> Callable | None:
        """What runs for ``args``: stored code, else (``compile``) numba's dispatcher, after
        compiling or loading it for their types and storing its code; else None."""
        try:
            key = ",".join(typekey(a) for a in args)
        except TypeError:
            return self._dispatcher() if compile else None
        fn = self._fns.get(key)
        if fn is not None:
            return fn
        with self._lock:  # one load or compile per key, whichever thread comes first
            fn = self._fns.get(key)
            if fn is None:
                fn = load(self.name, self.sources, key)
                if fn is None:
                    if not compile:
                        return None
                    with compiling(self.name, self.sources, key):
                        # another process may have compiled it while this one waited
                        fn = load(self.name, self.sources, key) or self._compile(key, args)
                self._fns[key] = fn
        return fn

    def _compile(self, key: str, args: tuple) -> Callable:
        """numba's dispatcher compiled for ``args``' types, its code stored."""
        log.info("compiling %s for this machine (once: its code is stored for later runs)",
                 self.name)
        from l3cli.startup import preload_scipy_blas

        preload_scipy_blas()  # numba's first use, without scipy.linalg's __init__
        fn = self._dispatcher()
        sig = tuple(fn.typeof_pyval(a) for a in args)
        with self._context():
            fn.compile(sig)
        save(self.name, self.sources, key, fn, args)
        return fn

    def stored(self) -> bool:
        """Whether any code of this function is stored for this machine and these sources."""
        return stored_any(self.name, self.sources)

    def __call__(self, *args: Any) -> Any:
        return self.function(*args)(*args)
