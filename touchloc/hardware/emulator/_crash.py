"""Crash a session-log writer with SIGKILL, again and again, and count what survives.

Each cycle starts a Python process (a fresh interpreter, or a fork of this one) that opens
the log for appending and writes records as fast as it can (each large enough to take
several ``write`` calls, so a kill often lands mid-record), printing the number of every
record whose ``append`` returned. The parent kills it with ``SIGKILL`` at a random moment
after its first acknowledged record. A record whose ``append`` returned (it was
acknowledged on stdout) must still be readable afterwards.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["kill_cycles"]

def _write_forever(path, cycle: int, fsync: bool, chunked: bool, out) -> None:
    """The writer's body: append records to ``path`` forever, acknowledging each on ``out``.

    Runs in the killed process, started either as a fresh interpreter or forked.
    """
    from touchloc.hardware.session import SessionLog
    from touchloc.models import Contacts
    from touchloc.planners import GuardedTouch, TouchResult

    t = GuardedTouch((0, 0, 0.1), (0, 0, -1), 0.05, name="down")
    pts = np.linspace(0, 0.01, 3 * 400).reshape(400, 3)   # ~30 kB per record: several writes
    c = Contacts(pts, np.tile([0.0, 0.0, 1.0], (400, 1)))
    log = SessionLog(path, fsync=fsync)
    if chunked:  # a writer whose record reaches the file in several system calls (as over NFS)
        raw, fh = log._fh.write, log._fh

        def write(text):
            for i in range(0, len(text), 4096):
                raw(text[i:i + 4096])
                fh.flush()
                time.sleep(0.002)  # a slow device: the kill often lands inside a record
            return len(text)

        log._fh.write = write
    out.write("ready\n")
    out.flush()
    k = 0
    while True:
        log.append(TouchResult(t, 0.02, c), finger=1, cycle=cycle, k=k)
        out.write(f"{k}\n")
        out.flush()
        k += 1


_WRITER = r"""
import sys
from touchloc.hardware.emulator._crash import _write_forever
_write_forever(sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", sys.argv[4] == "1", sys.stdout)
"""


def _start_exec(path, cycle, fsync, chunked, env):
    """A fresh interpreter: returns (pid, readable pipe of its acknowledgements, wait)."""
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path), str(cycle), "1" if fsync else "0",
                             "1" if chunked else "0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
    return proc.pid, proc.stdout, proc.wait


def _start_fork(path, cycle, fsync, chunked, env):
    """A forked child of this process (its modules already imported): same return."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: write until killed; never return into the caller's code
        try:
            os.close(r)
            _write_forever(str(path), cycle, fsync, chunked, os.fdopen(w, "w"))
        finally:
            os._exit(1)
    os.close(w)
    return pid, os.fdopen(r, "rb"), lambda: os.waitpid(pid, 0)


def kill_cycles(path, n_cycles: int, *, rng=None, max_delay: float = 0.15, fsync: bool = False,
                chunked: float = 0.5, start: str = "exec", check_every: int = 1) -> dict:
    """Run ``n_cycles`` writer processes on one log, SIGKILL each; return the tallies.

    ``start="exec"`` starts each writer as a fresh interpreter (``python -c``);
    ``start="fork"`` forks it from this process, which skips the interpreter's start and
    imports (seconds each on a busy machine) and runs the same writer code. The whole log
    is read back after every ``check_every``-th kill and after the last one.

    A fraction ``chunked`` of the writers push each record to the file in 4 kB pieces
    (one ``write`` system call each, 2 ms apart), so that kills tear records; the others write each
    record with one call, as :class:`SessionLog` does.

    Returns a dict: ``cycles``, ``acked`` (records whose append returned, over all cycles),
    ``read`` (records read back after the last cycle), ``lost`` (acked records missing:
    must be 0), ``torn`` (torn lines seen before repair), ``after_repair`` (records read
    after :func:`repair_session`), ``torn_after_repair`` (must be 0).
    """
    from ..session import TornRecordWarning, check_session, repair_session

    if start not in ("exec", "fork"):
        raise ValueError(f"start must be 'exec' or 'fork', got {start!r}")
    launch = _start_exec if start == "exec" else _start_fork
    if start == "fork":  # the child needs these imported already, or it pays for them
        from ...models import Contacts  # noqa: F401
        from ...planners import TouchResult  # noqa: F401
        from ..session import SessionLog  # noqa: F401
    rng = np.random.default_rng(rng)
    path = Path(path)
    acked: set = set()
    env = dict(os.environ)
    for cycle in range(int(n_cycles)):
        pid, pipe, wait = launch(path, cycle, fsync, bool(rng.random() < chunked), env)
        first = pipe.readline()
        if first.strip() != b"ready":
            os.kill(pid, signal.SIGKILL)
            wait()
            pipe.close()
            raise RuntimeError(f"writer did not start (cycle {cycle}): {first!r}")
        # the random delay runs from the first acknowledged record, so that a loaded machine
        # that is slow to schedule the writer cannot turn every cycle into an empty one
        ack0 = pipe.readline()
        time.sleep(float(rng.uniform(0.0, max_delay)))
        os.kill(pid, signal.SIGKILL)
        wait()
        out = ack0 + pipe.read()
        pipe.close()
        for line in out.split(b"\n")[:-1]:  # the last piece may itself be cut
            if line.strip().isdigit():
                acked.add((cycle, int(line)))
        if (cycle + 1) % max(1, int(check_every)) and cycle + 1 < int(n_cycles):
            continue
        # every acknowledged record is readable now, whatever the torn lines
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TornRecordWarning)
            chk = check_session(path)
        have = {(r.extra.get("cycle"), r.extra.get("k")) for r in chk.records}
        missing = acked - have
        if missing:
            return {"cycles": cycle + 1, "acked": len(acked), "read": len(have), "lost": len(missing),
                    "torn": len(chk.torn), "after_repair": None, "torn_after_repair": None}
    chk = check_session(path)
    have = {(r.extra.get("cycle"), r.extra.get("k")) for r in chk.records}
    dropped = repair_session(path)
    chk2 = check_session(path)
    have2 = {(r.extra.get("cycle"), r.extra.get("k")) for r in chk2.records}
    return {"cycles": int(n_cycles), "acked": len(acked), "read": len(have), "lost": len(acked - have),
            "torn": len(chk.torn), "dropped_by_repair": dropped, "after_repair": len(have2),
            "lost_by_repair": len(have - have2), "torn_after_repair": len(chk2.torn)}
