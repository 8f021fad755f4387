"""The ``touchloc`` command.

Each subpackage that offers commands has a ``_cli.py`` module with a
``register(subparsers)`` function; this module only collects them and holds the few
helpers every command shares (warnings, mesh arguments, interruption, diagnosis).
"""

from __future__ import annotations

import _thread
import argparse
import atexit
import importlib
import os
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

from .errors import TouchlocError, ValidationError

#: modules whose register(subparsers) adds subcommands, in help order
COMMAND_MODULES = [
    "touchloc._demo",
    "touchloc.belief._cli",
    "touchloc.planners._cli",
    "touchloc.dnf._cli",
    "touchloc.hardware._cli",
    "touchloc.recognition._cli",
    "touchloc.mapping._cli",
    "touchloc.experiments._cli",
    "touchloc._warmup",
]

#: exit status after Ctrl-C (128 + SIGINT), as shells report it
EXIT_INTERRUPTED = 128 + signal.SIGINT


def _add_verbosity(p, *, top: bool):
    # On a subcommand the defaults are SUPPRESS, so `touchloc -v localize` and
    # `touchloc localize -v` both work and neither overwrites the other.
    kw = {} if top else {"default": argparse.SUPPRESS}
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", action="store_true", help="print no warnings", **({"default": False} if top else kw))
    g.add_argument("-v", "--verbose", action="count",
                   help="print more: the category and origin of each warning, tracebacks of errors",
                   **({"default": 0} if top else kw))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="touchloc", description="Bayesian tactile localisation and mapping.")
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    _add_verbosity(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # that subpackage offers no commands (yet)
            raise
        mod.register(sub)
    for p in sub.choices.values():
        _add_verbosity(p, top=False)
    return parser


def _show_warning(verbose: int):
    def show(message, category, filename, lineno, file=None, line=None):
        if verbose:
            text = f"touchloc: {category.__name__}: {message} ({filename}:{lineno})"
        else:
            text = f"touchloc: warning: {message}"
        print(text, file=sys.stderr if file is None else file, flush=True)

    return show


def main(argv=None) -> int:
    """Run one ``touchloc`` command (``argv`` as on the command line); its exit status.

    Ctrl-C is handled as in :func:`run` while the command works (one line, status 130);
    the previous SIGINT handler is put back afterwards.
    """
    intr = _Interrupts()
    if not intr.install():
        return _main(argv, intr)
    try:
        return _main(argv, intr)
    finally:
        intr.uninstall()


def run() -> None:
    """Entry point of the ``touchloc`` program and of ``python -m touchloc``: exits the process.

    The Ctrl-C handler goes in before anything heavy is imported, and stays until the
    process is gone (see :class:`_Interrupts`).
    """
    intr = _Interrupts()
    intr.install()
    atexit.register(_ignore_interrupts)  # registered first, so it runs after every other atexit callback
    try:
        status = _main(None, intr)
    except KeyboardInterrupt:
        # in the few bytecodes between the command's return and here, or raised again (the
        # first one lost) before the command's own handler could acknowledge it
        intr.handled()
        print(f"{intr.label}: interrupted", file=sys.stderr, flush=True)
        status = EXIT_INTERRUPTED
    intr.finished = status
    sys.exit(status)


def _main(argv, intr) -> int:
    args = None
    label = "touchloc"
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command:
            label = intr.label = f"touchloc {args.command}"
        if args.version:
            from . import __version__

            print(__version__)
            return 0
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        with warnings.catch_warnings():
            if args.quiet:
                warnings.simplefilter("ignore")
            else:
                warnings.simplefilter("always" if args.verbose else "default")
                warnings.showwarning = _show_warning(args.verbose)
            from ._warmup import CompileNotice

            with CompileNotice(enabled=not args.quiet) as compiling:  # says so when numba compiles
                status = int(args.func(args) or 0)
            if compiling.count and not args.quiet:
                from .models._kernels import _NB

                later = ("later runs load them from the cache" if _NB["cache"] else
                         "no writable cache directory, so every run compiles: set NUMBA_CACHE_DIR")
                print(f"touchloc: compiled {compiling.count} kernels in {compiling.seconds:.0f} s; {later}",
                      file=sys.stderr, flush=True)
            return status
    except TouchlocError as exc:
        if args is not None and args.verbose > 1:
            raise
        print(f"{label}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        intr.handled()
        print(f"{label}: interrupted", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    except SystemError as exc:
        # Ctrl-C inside C code that calls back into Python arrives wrapped in a SystemError
        if not _caused_by_interrupt(exc):
            raise
        intr.handled()
        print(f"{label}: interrupted", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED


def _caused_by_interrupt(exc) -> bool:
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


# -- Ctrl-C --------------------------------------------------------------------------------
#
# Python turns SIGINT into a KeyboardInterrupt at whatever bytecode the main thread runs
# next. In a few places of the libraries touchloc uses that is not safe, and the handler
# below holds the interruption until the main thread has left them:
#  * numba and llvmlite (loading kernels from numba's cache, compiling, importing them):
#    an exception there can leave LLVM objects half made, which crashes the process when
#    it exits (SIGSEGV), or it is raised inside a ctypes callback, which swallows it (the
#    command goes on and exits 0);
#  * a thread being joined (scipy's cKDTree queries with workers=-1 run in threads): the
#    interrupted join leaves them running on memory that the exiting interpreter frees;
#  * numpy's ``npy_ctypes_check``, which numpy's C code calls while it builds a dtype and
#    whose exceptions it clears: an interruption there is lost (the command goes on and
#    exits 0).
# Elsewhere, C code that calls back into Python may clear an exception too, at places not
# listed here (ctypes callbacks report it as "ignored" and return). So an interruption raised
# is watched: when the main thread is seen handling it (in an except or finally block for a
# KeyboardInterrupt) or the command acknowledges it (interruption_handled), it was caught on
# purpose; when neither has happened after _REDELIVER_AFTER seconds, it was lost, and it is
# raised again.
# And once the command's work is over, a Ctrl-C must not kill the process by the signal:
# Python puts the default action back while it finalises, so a Ctrl-C then ends the
# process with no message and status -2. The program ignores SIGINT from its last
# atexit callback on.

_HOLD_PACKAGES = frozenset({"numba", "llvmlite"})
_HOLD_CALLS = frozenset({("threading", "join"), ("threading", "_wait_for_tstate_lock"),
                         ("numpy._core._internal", "npy_ctypes_check"),
                         ("numpy.core._internal", "npy_ctypes_check")})
#: seconds an interruption may wait before the command says why it has not stopped yet
_HOLD_NOTE_AFTER = 3.0
#: seconds after which an interruption raised but not yet handled by the command is taken as
#: lost (cleared by C code it was raised under) and raised again
_REDELIVER_AFTER = 1.0
#: the handler of the command running in this process, if any (see interruption_handled)
_ACTIVE = None


def interruption_handled() -> None:
    """Tell the running command's Ctrl-C handler that the interruption was caught on purpose
    (a subcommand that stops cleanly and carries on, or returns a status of its own), so
    that it is not taken as lost and raised again. A no-op outside a command."""
    if _ACTIVE is not None:
        _ACTIVE.handled()


def _in_unsafe_code(frame) -> bool:
    """Whether a KeyboardInterrupt raised in ``frame`` (the main thread's) would be unsafe."""
    depth = 0
    while frame is not None:
        mod = frame.f_globals.get("__name__") or ""
        if mod.partition(".")[0] in _HOLD_PACKAGES:
            return True
        if depth < 2 and (mod, frame.f_code.co_name) in _HOLD_CALLS:
            return True
        frame = frame.f_back
        depth += 1
    return False


def _flush_std():
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except (OSError, ValueError, AttributeError):
            pass


class _Interrupts:
    """The SIGINT handler of a command.

    Raises KeyboardInterrupt in the main thread, unless that thread is in code where the
    exception is unsafe (:func:`_in_unsafe_code`): then the interruption is held, and a
    watcher thread delivers it again (``_thread.interrupt_main``) as soon as the main
    thread has left that code. A second Ctrl-C while one is held ends the process at once
    (status 130). An interruption raised is watched until the command is seen handling it
    or acknowledges it (:meth:`handled`); one that neither happened to within
    ``_REDELIVER_AFTER`` seconds was cleared by C code it was raised under, and is raised
    again. After the work (``finished`` set), Ctrl-C ends the process at once with the
    command's own status.
    """

    def __init__(self):
        self.label = "touchloc"
        self.finished = None
        self.held = False
        self.redelivering = False
        self.raised_at = None
        self._previous = None
        self._main = threading.main_thread().ident
        self._lock = threading.RLock()

    def install(self) -> bool:
        global _ACTIVE
        if threading.current_thread() is not threading.main_thread():
            return False  # signal handlers can only be set from the main thread
        self._previous = signal.signal(signal.SIGINT, self)
        _ACTIVE = self
        return True

    def uninstall(self):
        global _ACTIVE
        self.held = False
        self.raised_at = None
        if _ACTIVE is self:
            _ACTIVE = None
        if signal.getsignal(signal.SIGINT) is self:
            signal.signal(signal.SIGINT, self._previous if self._previous is not None else signal.default_int_handler)

    def __call__(self, signum, frame):
        if self.finished is not None:
            _flush_std()
            os._exit(self.finished)
        # the watcher reads and sets the same state; the lock keeps it from delivering again
        # between this call's decision and its state change (re-entrant: a signal can arrive
        # while the handler runs)
        with self._lock:
            if self.held and not self.redelivering:  # a second Ctrl-C while the first waits: stop now
                print(f"{self.label}: interrupted", file=sys.stderr)
                _flush_std()
                os._exit(EXIT_INTERRUPTED)
            self.redelivering = False
            if _in_unsafe_code(frame):
                if not self.held:
                    self.held = True
                    threading.Thread(target=self._watch, name="touchloc-interrupt", daemon=True).start()
                return
            self.held = False
            if self.raised_at is None:
                threading.Thread(target=self._confirm, name="touchloc-interrupt-confirm", daemon=True).start()
            self.raised_at = time.monotonic()
        raise KeyboardInterrupt

    def handled(self):
        """The command has caught the interruption: nothing more to deliver."""
        with self._lock:
            self.raised_at = None

    def _main_handles_interrupt(self) -> bool:
        """Whether the main thread is inside an ``except`` or ``finally`` block for a
        KeyboardInterrupt now: code that caught it (a sweep recording its running trials, a
        driver stopping the hand) is dealing with it, so it was not lost."""
        current = getattr(sys, "_current_exceptions", None)
        if current is None:  # pragma: no cover - CPython has it
            return True      # (then nothing is ever raised again)
        exc = current().get(self._main)
        if isinstance(exc, tuple):  # Python < 3.12: (type, value, traceback)
            exc = exc[1]
        return isinstance(exc, KeyboardInterrupt)

    def _main_unsafe(self):
        """Whether the main thread runs unsafe code now (:func:`_in_unsafe_code`); None when
        it is gone."""
        frame = sys._current_frames().get(self._main)
        if frame is None:
            return None
        try:
            return _in_unsafe_code(frame)
        finally:
            del frame

    def _confirm(self):
        # an interruption raised but not handled within _REDELIVER_AFTER s was cleared by
        # the C code it was raised under: raise it again (where it is safe to)
        while True:
            time.sleep(0.05)
            with self._lock:
                if self.raised_at is None or self.finished is not None:
                    return
                if self._main_handles_interrupt():
                    self.raised_at = None  # caught by the command's own code: not lost
                    return
                if self.held or self.redelivering or time.monotonic() - self.raised_at < _REDELIVER_AFTER:
                    continue
                unsafe = self._main_unsafe()
                if unsafe is None:
                    return
                if not unsafe:
                    self.raised_at = time.monotonic()
                    _thread.interrupt_main(signal.SIGINT)

    def _watch(self):
        t0 = time.monotonic()
        noted = False
        while True:
            time.sleep(0.02)
            with self._lock:
                if not self.held:
                    return
                if self.redelivering:
                    continue  # the main thread has not run the handler yet (busy in compiled code)
                unsafe = self._main_unsafe()
                if unsafe is None:
                    return
                if not unsafe:
                    self.redelivering = True
                    _thread.interrupt_main(signal.SIGINT)
                    continue
            if not noted and time.monotonic() - t0 > _HOLD_NOTE_AFTER:
                noted = True
                print(f"{self.label}: stopping when the kernels are compiled or loaded; press Ctrl-C again "
                      "to stop at once", file=sys.stderr, flush=True)


def _ignore_interrupts():
    # the program's last atexit callback: from here on Python finalises, with SIGINT's
    # default action unless it is ignored
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except (ValueError, OSError):
        pass


# -- helpers shared by the subcommands -----------------------------------------------

def add_mesh_argument(p, *, name: str = "--mesh", default=None, required: bool = False, help_extra: str = ""):
    """``--mesh`` (a mesh file or a bundled name) and ``--scale`` (factor to metres)."""
    from .data import MESHES

    p.add_argument(name, default=default, required=required,
                   help=f"mesh file (any format trimesh reads: .obj, .stl, .ply, ...) or a bundled name "
                        f"({', '.join(sorted(MESHES))}){help_extra}")
    p.add_argument("--scale", default=None,
                   help="factor from the file's units to metres, e.g. 0.001 for a file in millimetres; "
                        "applies to bundled meshes too (on top of their own scaling)")


def parse_scale(value) -> float | None:
    if value is None:
        return None
    try:
        s = float(value)
    except (TypeError, ValueError):
        raise ValidationError(f"--scale must be a positive number (e.g. 0.001 for millimetres), got {value!r}") from None
    if not (s > 0 and s < float("inf")):
        raise ValidationError(f"--scale must be a positive finite number, got {value!r}")
    return s


def split_mesh_spec(spec: str):
    """``path.obj:0.001`` -> ("path.obj", 0.001); a plain name or path -> (spec, None)."""
    head, sep, tail = spec.rpartition(":")
    if sep and head and not Path(spec).exists():
        try:
            return head, parse_scale(tail)
        except ValidationError:
            pass  # e.g. a Windows drive letter: not a scale
    return spec, None


def load_mesh(spec: str, scale=None, *, name: str | None = None):
    """A MeshObject from a file path or a bundled name, times ``scale`` (None: 1).

    ``spec`` may carry its own scale as ``path.obj:0.001``, which wins over ``scale``.
    """
    from .data import MESHES, load_object
    from .models import MeshObject

    spec, own = split_mesh_spec(spec)
    s = parse_scale(scale) if own is None else own
    if spec in MESHES and not Path(spec).exists():
        obj = load_object(spec)
        if s is not None and s != 1.0:
            obj = MeshObject.from_file(_bundled_path(spec), scale=MESHES[spec] * s, name=name or spec)
        return obj
    p = Path(spec)
    if not p.exists():
        raise ValidationError(f"mesh {spec!r}: no such file, and not a bundled name ({', '.join(sorted(MESHES))})")
    if p.is_dir():
        raise ValidationError(f"mesh {spec!r} is a directory, expected a mesh file")
    return MeshObject.from_file(p, scale=1.0 if s is None else s, **({"name": name} if name else {}))


def _bundled_path(name):
    from .data import mesh_path

    return mesh_path(name)


def diagnose(obj, contacts, region, belief=None, *, sigma_pos: float | None = None) -> list[str]:
    """Reasons a localisation may have failed, and what to check (units, region, mesh)."""
    import numpy as np

    lines = []
    P = contacts.points
    ext_c = float(np.ptp(P, axis=0).max()) if len(P) > 1 else 0.0
    ext_m = float(np.max(obj.extents))
    if belief is not None and "mean_cost_at_map" in belief.info:
        k = float(np.sqrt(max(belief.info["mean_cost_at_map"], 0.0)))
        d = f" (x sigma_pos = {k * sigma_pos * 1e3:.3g} mm)" if sigma_pos else ""
        lines.append(f"at the best pose the contacts lie {k:.3g} sigma{d} from the surface on average, "
                     "position and normal error together")
        if k > 1e4:
            lines.append("that many sigma suggests a unit mismatch: a mesh or CSV in millimetres read as metres "
                         "(try --scale 0.001 for the mesh, or convert the CSV to metres)")
    if ext_m > 0 and ext_c > 100 * ext_m:
        lines.append(f"the contacts span {ext_c:.3g} m but the mesh only {ext_m:.3g} m: are the contacts in "
                     "millimetres? (the CSV must be in metres)")
    elif ext_c > 0 and ext_m > 100 * ext_c and len(P) >= 4:
        lines.append(f"the mesh spans {ext_m:.3g} m but the contacts only {ext_c:.3g} m: is the mesh in "
                     "millimetres? (try --scale 0.001)")
    c = np.asarray(getattr(region, "center", np.zeros(3)), dtype=float)[:3]
    far = float(np.max(np.linalg.norm(P - c, axis=1)))
    reach = float(np.linalg.norm(getattr(region, "half_extent", 0.0))) + float(obj.radius)
    if far > reach:
        lines.append(f"a contact lies {far:.3g} m from the region centre, beyond reach of the object anywhere in the "
                     f"region ({reach:.3g} m): check --center and --half-extent")
    lines.append("check: units (metres everywhere; --scale for the mesh), the region (--center, --half-extent, "
                 "--rotation), and that the mesh is the touched object")
    return lines


class heartbeat:
    """Context manager: print ``label: still working (N s)`` to stderr every ``interval`` s.

    For long calls that report no progress of their own; a daemon thread, stopped on exit
    (also on Ctrl-C).
    """

    def __init__(self, label: str, interval: float = 10.0):
        import threading

        self.label, self.interval = label, float(interval)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        import time

        t0 = time.monotonic()
        while not self._stop.wait(self.interval):
            print(f"{self.label}: still working ({time.monotonic() - t0:.0f} s)", file=sys.stderr, flush=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(timeout=1.0)
        return False


if __name__ == "__main__":  # pragma: no cover
    run()
