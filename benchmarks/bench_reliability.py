"""Reliability: hostile inputs, corrupted replies and killed writers, and what came back.

Three tallies, each counted in this run:

1. Every public callable of the subpackages (the names in their ``__all__``), called once per (parameter, hostile value) pair: the harness of
   tests/test_fuzz_public.py, with a longer time limit per call.
2. SDH-2 driver calls over replies of the real emulator corrupted at a rate of 0.5.
3. Session-log writer processes killed with SIGKILL mid-stream; acknowledged records
   are counted against the records read back, before and after ``repair_session``. The
   100 cycles fork their writers (the same writer code without an interpreter start and
   imports, seconds each on a busy machine); a shorter run starts fresh interpreters.
"""

from __future__ import annotations

import collections
import sys
import tempfile
import time
from pathlib import Path

TITLE = "Reliability: hostile inputs, corrupted replies, killed writers"


def _harness():
    """The hostile-input harness of tests/test_fuzz_public.py."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import test_fuzz_public

    return test_fuzz_public


def _fuzz_public(time_limit: float):
    import os

    F = _harness()
    rows = []
    total = collections.Counter()
    old = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:  # hostile calls write files named by their arguments
        os.chdir(scratch)
        try:
            for name, fn, params in F.CALLABLES:
                c = collections.Counter()
                for p in params:
                    for b in sorted(F.BAD):
                        kind, _ = F.run_one(fn, params, p.name, F.BAD[b], time_limit_s=time_limit,
                                            extra=F.CHEAP.get(name))
                        c[kind] += 1
                total.update(c)
                rows.append((name, c))
        finally:
            os.chdir(old)
    return total, rows, len(F.CALLABLES)


def _fuzz_methods(time_limit: float):
    """The same for the public methods of the core classes (tests/test_fuzz_methods.py)."""
    import os

    _harness()
    import test_fuzz_methods as M

    total, unclean = collections.Counter(), []
    old = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:
        os.chdir(scratch)
        try:
            for entry in M.METHODS:
                c = collections.Counter()
                for p in entry[3]:
                    for b in sorted(M.BAD):
                        kind, _ = M._call(entry, p.name, M.BAD[b], time_limit_s=time_limit)
                        c["ok" if kind == "nan" and entry[0] in M.NAN_DOCUMENTED else kind] += 1
                total.update(c)
                if c["raw"] or c["hang"] or c["nan"]:
                    unclean.append((entry[0], c))
        finally:
            os.chdir(old)
    classes = sorted({e[0].rsplit(".", 1)[0] for e in M.METHODS})
    return total, unclean, len(M.METHODS), classes, M


def _open(transport, emu, channel):
    import can
    import serial

    from touchloc.hardware.emulator import CANServer, PtyServer, TCPServer

    if transport == "tcp":
        srv = TCPServer(emu).start()
        return srv, serial.serial_for_url(srv.url, timeout=0.05)
    if transport == "pty":
        srv = PtyServer(emu).start()
        return srv, serial.serial_for_url(srv.path, baudrate=115200, timeout=0.05)
    srv = CANServer(emu, channel=channel).start()
    return srv, can.Bus(interface="virtual", channel=channel)


def _close(transport, srv, port):
    try:
        port.shutdown() if transport == "can" else port.close()
    finally:
        srv.close()


SDH2_FAULTS = ("error", "drop", "truncate", "lose", "garbage", "silence", "disconnect")
DSA_FAULTS = ("crc", "error", "drop", "truncate", "lose", "garbage", "silence", "disconnect")
TRANSPORTS = ("tcp", "pty", "can")


def _fault_matrix():
    """Each fault once on each transport: the error that came back, and (SDH-2) whether
    ``stop`` reached the device."""
    import numpy as np

    from touchloc.errors import TouchlocError
    from touchloc.hardware import SDH2, DSACON32m
    from touchloc.hardware.emulator import DSACON32mEmulator, SDH2Emulator, SimHand

    out = {}
    for i, (kind, tr) in enumerate((k, t) for k in SDH2_FAULTS for t in TRANSPORTS):
        emu = SDH2Emulator(SimHand(time_scale=20.0))
        srv, port = _open(tr, emu, f"bench-sdh-{i}")
        try:
            hand = SDH2.over_can(port, timeout=0.5) if tr == "can" else SDH2(port, timeout=0.5)
            hand.move(np.radians([0, 60, 10, 10, 10, 10, 10]))        # mid-move when the fault hits
            n = len(emu.received)
            emu.faults.add(kind, on="state", code=17)
            try:
                hand.wait_until_idle(5.0)
                hand.wait_until_idle(5.0)
                got = "no error"
            except TouchlocError as exc:
                got = type(exc).__name__
            except Exception as exc:  # noqa: BLE001 - a raw exception is what this counts
                got = f"raw {type(exc).__name__}"
            end = time.monotonic() + 2.0
            while "stop" not in emu.received[n:] and time.monotonic() < end:
                time.sleep(0.01)
            if "stop" in emu.received[n:]:
                got += ", stop sent"
            elif got == "DeviceDisconnected":
                got += " (line closed: no stop can reach the hand)"
            else:
                got += ", **no stop**"
            out[("SDH-2", kind, tr)] = got
        finally:
            _close(tr, srv, port)
    shapes = [(14, 6), (13, 6)] * 3
    mats = [np.full(sh, 100, np.uint16) for sh in shapes]
    for i, (kind, tr) in enumerate((k, t) for k in DSA_FAULTS for t in TRANSPORTS):
        emu = DSACON32mEmulator(frame_source=lambda: mats)
        srv, port = _open(tr, emu, f"bench-dsa-{i}")
        try:
            dev = DSACON32m(port, timeout=0.5, open_timeout=0.5)
            emu.faults.add(kind, on=0x03, code=17)
            try:
                dev.read_frame()
                dev.read_frame()
                got = "frames read (garbage skipped)" if kind == "garbage" else "no error"
            except TouchlocError as exc:
                got = type(exc).__name__
            except Exception as exc:  # noqa: BLE001
                got = f"raw {type(exc).__name__}"
            out[("DSACON32m", kind, tr)] = got
        finally:
            _close(tr, srv, port)
    return out


def run(quick: bool = False) -> str:
    from touchloc.hardware.emulator._corrupt import fuzz_sdh2
    from touchloc.hardware.emulator._crash import kill_cycles

    out = []
    t = time.perf_counter()
    time_limit_s = 2.0 if quick else 3.0
    total, rows, n_callables = _fuzz_public(time_limit_s)
    dt = time.perf_counter() - t
    n = sum(total.values())
    F = _harness()
    kinds = ", ".join(f"`{k}`" for k in sorted(F.BAD))
    pkgs = ", ".join(m.split(".")[-1] for m in F.MODULES)
    out.append(f"**Public callables** ({n_callables} names of {pkgs}; every "
               f"parameter x {len(F.BAD)} hostile values, one at a time, the other arguments ordinary; "
               f"{n} calls in {dt:.0f} s, {time_limit_s:g} s allowed per call). Hostile values: {kinds}.\n")
    out.append("| outcome | calls | share |\n|---|---:|---:|")
    for kind, label in [("error", "TouchlocError"), ("ok", "valid result"), ("raw", "raw exception"),
                        ("hang", "over the time limit"), ("nan", "NaN in the result")]:
        out.append(f"| {label} | {total[kind]} | {100 * total[kind] / max(1, n):.1f} % |")
    bad = [(name, c) for name, c in rows if c["raw"] or c["hang"] or c["nan"]]
    if bad:
        out.append("\nNames with unclean outcomes (raw / hang / NaN):\n")
        out.append(", ".join(f"`{name}` ({c['raw']}/{c['hang']}/{c['nan']})" for name, c in bad))
    else:
        out.append(f"\nNo name had an unclean outcome. NaN results are accepted only where the hostile value "
                   f"held NaN and the docstring says \"NaN in, NaN out\" (`dnf.sigmoid`, `dnf.circular_convolve`, "
                   f"`dnf.diagonal_sum`: per-step array helpers that do not scan their input).")

    t = time.perf_counter()
    total, unclean, n_methods, classes, M = _fuzz_methods(time_limit_s)
    dt = time.perf_counter() - t
    n = sum(total.values())
    out.append(f"\n**Public methods** ({n_methods} methods of {len(classes)} classes of "
               f"{', '.join(m.split('.')[-1] for m in M.METHOD_MODULES)}, each on a fresh instance built from "
               f"ordinary values; the same hostile values one parameter at a time; {n} calls in {dt:.0f} s): "
               f"{total['error']} TouchlocError, {total['ok']} valid results, **{total['raw']} raw exceptions, "
               f"{total['hang']} over the time limit, {total['nan']} NaN results**"
               + (" (" + ", ".join(f"`{k}` ({c['raw']}/{c['hang']}/{c['nan']})" for k, c in unclean) + ")"
                  if unclean else "") + ". NaN accepted only where the docs say so: "
               + "; ".join(f"`{k}`: {v}" for k, v in M.NAN_DOCUMENTED.items()) + ". Left out: "
               + "; ".join(sorted({v for v in M.EXCLUDED.values()})) + f" ({len(M.EXCLUDED)} methods, and "
               f"{', '.join(sorted(M.DEVICES))}). The SDH-2 and DSACON32m drivers are called on one emulated rig "
               "(their bytes over loopback TCP) shared by every call. When this suite was added it found 67 method entries letting raw exceptions (or NaN) through: counts, levels, "
               "tolerances and flags converted with `int()`/`float()`/`bool` or compared unchecked "
               "(`PoseRegion.sample(n)`, `MeshObject.sample_surface(n)`, `ParticleBelief.credible_set(level)`, "
               "`ShapeMap.to_mesh(resolution)`, `Plan.ranking(k)`, `SDH2Kinematics.pad_frame(matrix)`), reference poses, paths, objects and "
               "candidate lists taken unchecked (`PoseRegion.to_local(ref)`, `Contacts.to_csv(path)`, "
               "`TactileScanner.scan(obj)`, `OneStepPlanner.plan(candidates)`), and `PoseRegion.perturb` "
               "returning NaN for an absurd scale; and, on an ordinary call, `Sweep.from_toml` on a file that "
               "is not UTF-8 (a raw UnicodeDecodeError), `LocalLinearMap.predict` before `fit` (a raw "
               "AttributeError), `SDH2Kinematics.texel_points(matrix=None)` and `with_matrix_info(None)`; and on the "
               "drivers one: `SDH2.grip(wait=-inf)` took any truthy value as a request to wait. Mended on the way: `TactileScanner.scan(object_pose=...)` accepted a reflection.")

    n_calls = 5_000 if quick else 20_000
    t = time.perf_counter()
    r = fuzz_sdh2(n_calls, rate=0.5, seed=2026)
    dt = time.perf_counter() - t
    out.append(f"\n**SDH-2 driver over corrupted replies** ({r['calls']} calls, {dt:.0f} s): "
               f"{r['ok']} valid results, {r['typed']} library errors "
               f"({', '.join(f'{k} {v}' for k, v in sorted(r['errors'].items()))}), "
               f"**{r['raw']} raw exceptions, {r['missing_stop']} failed calls without `stop`**.")

    t = time.perf_counter()
    fm = _fault_matrix()
    dt = time.perf_counter() - t
    out.append(f"\n**Fault matrix** (each fault injected by the emulator once per device and transport; "
               f"SDH-2 mid-move while waiting for idle, DSACON32m on a frame request; {dt:.0f} s). "
               f"`lose` drops 3 bytes of a reply, `truncate` cuts it, `drop` sends none, `silence` stops "
               f"answering, `disconnect` closes the line (a CAN device falls silent):\n")
    out.append("| device | fault | " + " | ".join(TRANSPORTS) + " |\n|---|---|" + "---|" * len(TRANSPORTS))
    for dev, kinds in (("SDH-2", SDH2_FAULTS), ("DSACON32m", DSA_FAULTS)):
        for kind in kinds:
            out.append(f"| {dev} | {kind} | " + " | ".join(fm[(dev, kind, tr)] for tr in TRANSPORTS) + " |")

    out.append("\n**Session log under `kill -9`**: each writer appends ~30 kB records (half of the writers in "
               "4 kB system calls, so that kills tear records) until SIGKILL at a random moment within 0.15 s; "
               "the log is then read back and every acknowledged record must be in it (a few more can be: a "
               "record may reach the file just before the kill stops its acknowledgement).\n")
    out.append("| writers | killed | log read back | acknowledged | read back | lost | torn lines | "
               "dropped by `repair_session` | lost by the repair | time |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for start, cycles, every in (("fork", 20 if quick else 100, 10), ("exec", 3 if quick else 10, 1)):
        t = time.perf_counter()
        with tempfile.TemporaryDirectory() as d:
            k = kill_cycles(Path(d) / "session.jsonl", cycles, rng=7, start=start, check_every=every)
        dt = time.perf_counter() - t
        label = "forked" if start == "fork" else "fresh interpreters"
        when = "after every kill" if every == 1 else f"after every {every}th kill"
        out.append(f"| {label} | {k['cycles']} | {when} | {k['acked']} | {k['read']} | **{k['lost']}** | {k['torn']} | "
                   f"{k.get('dropped_by_repair', 0)} | {k.get('lost_by_repair', 0)} | {dt:.0f} s |")
    return "\n".join(out) + "\n"
