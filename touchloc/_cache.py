"""On-disk caches: compiled kernels (numba) and expensive per-mesh structures.

Two things make a new process slow: compiling the numba kernels (tens of seconds, once
per install) and building per-mesh structures such as the fast likelihood's candidate
grid (seconds per mesh, once per mesh and parameters). Both are kept on disk.

Where
-----
``TOUCHLOC_CACHE_DIR`` names the directory; ``TOUCHLOC_CACHE_DIR=off`` (or ``0``,
``none``, ``false``, empty) turns the per-mesh cache off. Without it the directory is
``$XDG_CACHE_HOME/touchloc``, else ``~/.cache/touchloc``.

Per-mesh structures live in ``<dir>/<kind>/<mesh hash>-<key hash>.npz``. The key hashes
the mesh content (vertices after scaling and repair, faces, usable faces), the
structure's parameters, a format version and the source of the code that builds it, so
a changed mesh, parameter or builder never reads a stale file. Files are plain arrays
(``numpy.load(allow_pickle=False)``: loading runs no code), written to a temporary file
and moved into place with :func:`os.replace`, so concurrent processes never see half a
file. An unreadable or mismatched file is reported with a :class:`CacheWarning`,
rebuilt and overwritten; it never stops the computation.

Compiled kernels use numba's own cache (``cache=True``): next to the installed sources
when that directory is writable, else numba's per-user directory
(``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``), or ``NUMBA_CACHE_DIR`` when set.
When none of these is writable (a read-only install with a read-only home), kernels go
to ``<touchloc cache dir>/numba``; when that is not writable either, they are compiled
in every process (correct, only slower).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

__all__ = [
    "CacheWarning",
    "FORMAT_VERSION",
    "cache_dir",
    "mesh_hash",
    "structure_key",
    "cached_structure",
    "numba_cache_enabled",
    "stats",
    "events",
    "info",
    "clear",
]

#: bump when the on-disk layout of a cached structure changes
FORMAT_VERSION = 1
#: structures that took less than this to build (s) are not written (reading them back
#: would cost about as much)
MIN_SAVE_SECONDS = 0.2
ENV = "TOUCHLOC_CACHE_DIR"
_OFF = {"off", "0", "no", "none", "false", "disable", "disabled", ""}

#: counters of this process: ``hit``, ``miss``, ``write``, ``corrupt``, ``write_error``
stats: Counter = Counter()
#: (kind, outcome, seconds, mesh name) for each structure requested in this process,
#: outcome one of ``"loaded"``, ``"built"`` (and saved), ``"built-unsaved"``
events: list = []
#: > 0 while the cache is bypassed (structures of throw-away meshes)
suspended = 0


class CacheWarning(UserWarning):
    """A cache file could not be read or written; the structure was rebuilt in memory."""


# -- location ----------------------------------------------------------------------------

def cache_dir() -> Path | None:
    """The per-mesh cache directory, or None when ``TOUCHLOC_CACHE_DIR=off``."""
    env = os.environ.get(ENV)
    if env is not None:
        if env.strip().lower() in _OFF:
            return None
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "touchloc"


def _writable_dir(path) -> bool:
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


def numba_cache_enabled(source_file: str) -> bool:
    """Whether numba can keep the kernels of ``source_file`` on disk (``cache=`` flag).

    Numba looks in order at ``NUMBA_CACHE_DIR``, the ``__pycache__`` beside the source
    and its per-user directory, and fails at import when none is writable. This checks
    the same places first; when all fail it points numba at ``<cache_dir()>/numba``, and
    when that fails too it returns False (kernels are then compiled in each process).
    """
    import numba

    if numba.config.CACHE_DIR:
        return _writable_dir(numba.config.CACHE_DIR)
    if _writable_dir(os.path.join(os.path.dirname(os.path.abspath(source_file)), "__pycache__")):
        return True
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    if _writable_dir(base / "numba"):
        return True
    d = cache_dir()
    if d is None:  # the user turned touchloc's cache off: try its default place anyway
        d = base / "touchloc"
    if _writable_dir(d / "numba"):
        numba.config.CACHE_DIR = str(d / "numba")
        return True
    return False


# -- keys --------------------------------------------------------------------------------

def mesh_hash(obj) -> str:
    """SHA-256 (hex) of a MeshObject's geometry: vertices (in metres, after any scale and
    repair), faces and the faces with a usable normal. Cached on the object."""
    h = obj._cache.get("content_hash")
    if h is None:
        d = hashlib.sha256()
        for a in (obj.mesh.vertices, obj.mesh.faces, obj.valid_faces):
            a = np.ascontiguousarray(a)
            d.update(f"{a.dtype.str}{a.shape}".encode())
            d.update(a.tobytes())
        h = d.hexdigest()
        obj._cache["content_hash"] = h
    return h


_SOURCE_HASHES: dict = {}


def _source_hash(mod) -> str:
    f = getattr(mod, "__file__", None)
    if f is None:
        return "no-source"
    h = _SOURCE_HASHES.get(f)
    if h is None:
        try:
            h = hashlib.sha256(Path(f).read_bytes()).hexdigest()
        except OSError:
            h = "unreadable"
        _SOURCE_HASHES[f] = h
    return h


def _plain(v):
    """Parameters as JSON-able values; floats by repr (exact round trip)."""
    if isinstance(v, (bool, str)) or v is None:
        return v
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    a = np.asarray(v)
    if a.dtype.kind in "fiub":
        return [a.dtype.str, list(a.shape), hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()]
    raise TypeError(f"cache parameter of type {type(v).__name__} is not supported")


def structure_key(kind: str, obj, params: dict, code=()) -> str:
    """Hex key of one structure: format version, kind, mesh hash, parameters and the
    source of the modules in ``code`` (the builder's), so that any change gives a new key."""
    doc = {
        "format": FORMAT_VERSION,
        "kind": kind,
        "mesh": mesh_hash(obj),
        "params": {k: _plain(v) for k, v in sorted(params.items())},
        "code": [_source_hash(m) for m in code],
    }
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


# -- (de)serialisation of dataclasses of arrays --------------------------------------------

def _to_arrays(value) -> dict:
    if not dataclasses.is_dataclass(value):
        raise TypeError(f"only dataclasses of arrays and numbers can be cached, got {type(value).__name__}")
    out = {}
    for f in dataclasses.fields(value):
        v = getattr(value, f.name)
        if isinstance(v, np.ndarray):
            out[f"a_{f.name}"] = v
        elif isinstance(v, tuple):
            out[f"t_{f.name}"] = np.asarray(v)
        elif isinstance(v, (bool, np.bool_)):
            out[f"b_{f.name}"] = np.asarray(bool(v))
        elif isinstance(v, (int, np.integer)):
            out[f"i_{f.name}"] = np.asarray(int(v))
        elif isinstance(v, (float, np.floating)):
            out[f"f_{f.name}"] = np.asarray(float(v))
        else:
            raise TypeError(f"field {f.name} of {type(value).__name__} ({type(v).__name__}) cannot be cached")
    return out


def _from_arrays(cls, data) -> object:
    kw = {}
    for name in data.files:
        tag, _, field = name.partition("_")
        a = data[name]
        if tag == "a":
            kw[field] = a
        elif tag == "t":
            kw[field] = tuple(x.item() for x in a)
        elif tag == "b":
            kw[field] = bool(a)
        elif tag == "i":
            kw[field] = int(a)
        elif tag == "f":
            kw[field] = float(a)
        elif tag != "meta":
            raise ValueError(f"unexpected entry {name!r}")
    return cls(**kw)


# -- the cache ---------------------------------------------------------------------------

def _path(kind: str, obj, key: str) -> Path | None:
    d = cache_dir()
    if d is None:
        return None
    return d / kind / f"{mesh_hash(obj)[:16]}-{key[:24]}.npz"


def _load(path: Path, cls, key: str):
    with np.load(path, allow_pickle=False) as data:
        if "meta_key" not in data.files or str(data["meta_key"]) != key:
            raise ValueError("the key stored in the file does not match its name")
        return _from_arrays(cls, data)


def _save(path: Path, value, key: str) -> None:
    arrays = _to_arrays(value)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, meta_key=np.asarray(key), **arrays)
        os.chmod(tmp, 0o644)  # mkstemp makes it 0600; a shared cache directory should be readable
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def cached_structure(kind: str, obj, params: dict, build, cls, *, code=()):
    """The structure ``build()`` for mesh ``obj`` and ``params``, from disk when possible.

    Parameters
    ----------
    kind : str
        Name of the structure (a sub-directory of the cache), e.g. ``"candidate_grid"``.
    obj : MeshObject
    params : dict
        Everything besides the mesh that the structure depends on (numbers, strings,
        arrays).
    build : callable
        ``build() -> cls`` builds the structure; called on a miss.
    cls : type
        A dataclass whose fields are arrays, tuples of numbers, or numbers.
    code : sequence of modules
        Modules whose source the structure depends on; editing them invalidates it.

    Returns
    -------
    The structure, loaded or built. Counters in :data:`stats`, timings in :data:`events`.
    """
    t0 = time.perf_counter()
    path = None
    try:
        key = structure_key(kind, obj, params, code)
        path = None if suspended else _path(kind, obj, key)
    except (TypeError, OSError, RuntimeError) as exc:  # cannot even name the file: build
        warnings.warn(f"touchloc cache: {kind}: {exc}; building without the cache", CacheWarning, stacklevel=2)
    if path is not None and path.exists():
        try:
            value = _load(path, cls, key)
        except Exception as exc:  # any unreadable file: warn, rebuild, overwrite
            stats["corrupt"] += 1
            warnings.warn(f"touchloc cache: ignoring unreadable {path} ({type(exc).__name__}: {exc}); rebuilding it",
                          CacheWarning, stacklevel=2)
        else:
            stats["hit"] += 1
            events.append((kind, "loaded", time.perf_counter() - t0, obj.name))
            return value
    stats["miss"] += 1
    value = build()
    dt = time.perf_counter() - t0
    outcome = "built-unsaved"
    if path is not None and dt >= MIN_SAVE_SECONDS:
        try:
            _save(path, value, key)
        except (OSError, TypeError, ValueError) as exc:
            stats["write_error"] += 1
            warnings.warn(f"touchloc cache: could not write {path} ({exc}); set {ENV} to a writable "
                          f"directory, or {ENV}=off", CacheWarning, stacklevel=2)
        else:
            stats["write"] += 1
            outcome = "built"
    events.append((kind, outcome, time.perf_counter() - t0, obj.name))
    return value


def info() -> dict:
    """What the per-mesh cache holds: ``{"dir": path or None, "kinds": {kind: (files, bytes)}}``."""
    d = cache_dir()
    kinds = {}
    if d is not None and d.is_dir():
        for sub in sorted(p for p in d.iterdir() if p.is_dir() and p.name != "numba"):
            files = list(sub.glob("*.npz"))
            kinds[sub.name] = (len(files), sum(f.stat().st_size for f in files))
    return {"dir": d, "kinds": kinds}


def clear() -> int:
    """Delete every cached per-mesh structure (``*.npz`` under the cache directory's kinds,
    and stale temporary files); returns the number of files removed. Compiled kernels are
    numba's and stay."""
    d = cache_dir()
    n = 0
    if d is None or not d.is_dir():
        return 0
    for sub in d.iterdir():
        if sub.is_dir() and sub.name != "numba":
            for f in list(sub.glob("*.npz")) + list(sub.glob("*.tmp")):
                try:
                    f.unlink()
                    n += 1
                except OSError:
                    pass
    return n
