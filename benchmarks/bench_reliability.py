"""Reliability: hostile inputs, corrupted replies and killed writers, and what came back.

Three tallies, each counted in this run:

1. Every public callable of models, belief, planners and dnf (the names in their
   ``__all__``), called once per (parameter, hostile value) pair: the same harness as
   tests/test_fuzz_public.py, swept exhaustively instead of sampled.
2. SDH-2 driver calls over replies of the real emulator corrupted at a rate of 0.5.
3. Session-log writer processes killed with SIGKILL mid-stream; acknowledged records
   are counted against the records read back, before and after ``repair_session``.
"""

from __future__ import annotations

import collections
import sys
import tempfile
import time
from pathlib import Path

TITLE = "Reliability: hostile inputs, corrupted replies, killed writers"


def _fuzz_public(time_limit: float):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import test_fuzz_public as F

    rows = []
    total = collections.Counter()
    for name, fn, params in F.CALLABLES:
        c = collections.Counter()
        for p in params:
            for b in sorted(F.BAD):
                kind, _ = F.run_one(fn, params, p.name, F.BAD[b], time_limit_s=time_limit, extra=F.CHEAP.get(name))
                c[kind] += 1
        total.update(c)
        rows.append((name, c))
    return total, rows, len(F.CALLABLES)


def run(quick: bool = False) -> str:
    from touchloc.hardware.emulator._corrupt import fuzz_sdh2
    from touchloc.hardware.emulator._crash import kill_cycles

    out = []
    t = time.perf_counter()
    total, rows, n_callables = _fuzz_public(1.0 if quick else 2.0)
    dt = time.perf_counter() - t
    n = sum(total.values())
    out.append(f"**Public callables** ({n_callables} names; each parameter x {n // max(1, n_callables)} "
               f"hostile values on average; {n} calls in {dt:.0f} s):\n")
    out.append("| outcome | calls | share |\n|---|---:|---:|")
    for kind, label in [("error", "TouchlocError"), ("ok", "valid result"), ("raw", "raw exception"),
                        ("hang", "over the time limit"), ("nan", "NaN in the result")]:
        out.append(f"| {label} | {total[kind]} | {100 * total[kind] / max(1, n):.1f} % |")
    bad = [(name, c) for name, c in rows if c["raw"] or c["hang"] or c["nan"]]
    if bad:
        out.append("\nNames with unclean outcomes (raw / hang / NaN):\n")
        out.append(", ".join(f"`{name}` ({c['raw']}/{c['hang']}/{c['nan']})" for name, c in bad))

    n_calls = 5_000 if quick else 20_000
    t = time.perf_counter()
    r = fuzz_sdh2(n_calls, rate=0.5, seed=2026)
    dt = time.perf_counter() - t
    out.append(f"\n**SDH-2 driver over corrupted replies** ({r['calls']} calls, {dt:.0f} s): "
               f"{r['ok']} valid results, {r['typed']} library errors "
               f"({', '.join(f'{k} {v}' for k, v in sorted(r['errors'].items()))}), "
               f"**{r['raw']} raw exceptions, {r['missing_stop']} failed calls without `stop`**.")

    cycles = 20 if quick else 100
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        k = kill_cycles(Path(d) / "session.jsonl", cycles, rng=7)
    dt = time.perf_counter() - t
    out.append(f"\n**Session log under `kill -9`** ({k['cycles']} writer processes killed, {dt:.0f} s): "
               f"{k['acked']} acknowledged records, {k['read']} read back, **{k['lost']} lost**; "
               f"{k['torn']} torn lines skipped and reported, {k.get('dropped_by_repair', 0)} dropped by "
               f"`repair_session`, {k.get('lost_by_repair', 0)} records lost by the repair.")
    return "\n".join(out) + "\n"
