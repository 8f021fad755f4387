"""This checkout's DNF tracker step against another commit's, run by run.

    python benchmarks/ab_dnf_step.py REV [--rounds N]

Two worker processes, one importing touchloc from this checkout and one from ``git
archive REV``, time ``OrientationTracker().step`` over the benchmark's two data sets (the
dense 6-gon and the robustness sweep's base cell, ``bench_dnf.py``) in turn, in alternating
order, so that both see the same load on a shared machine. Each worker runs a first pass
untimed (numba's kernels load or compile there). The ratio is REV's median step time over
this checkout's; the workers also report the orientation after the last sample, so that a
change meant to keep the results shows whether it did. Prints a Markdown table; nothing is
written to docs/. :func:`paired` is the same measurement for ``bench_dnf.py``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import ROOT, TreeWorker, baseline_tree, table  # noqa: E402

#: the data sets timed (bench_dnf's two): the generator's dense default and the sweep's base cell
DATASETS = ("dense 6-gon", "base cell 6-gon")


def _worker() -> None:
    """Answer timing requests on stdin (one JSON line each) with this process's touchloc."""
    import touchloc
    from touchloc.dnf import OrientationTracker, generate_rotation_dataset

    print(json.dumps({"touchloc": str(Path(touchloc.__file__).resolve().parent.parent)}), flush=True)
    data = {}
    for line in sys.stdin:
        req = json.loads(line)
        name = req["dataset"]
        if name not in data:
            from bench_dnf import _BASE, _cell_kwargs

            kw = _cell_kwargs(_BASE) if name == DATASETS[1] else {}
            ds = generate_rotation_dataset(6, revolutions=req["revolutions"], rng=123, **kw)
            data[name] = list(ds.samples())
            tr = OrientationTracker()
            for a, odo in data[name]:      # untimed: kernels load (or compile) here
                tr.step(a, odo)
        tr = OrientationTracker()
        times = []
        for a, odo in data[name]:
            t0 = time.perf_counter()
            tr.step(a, odo)
            times.append(time.perf_counter() - t0)
        print(json.dumps({"times": times, "orientation": tr.orientation}), flush=True)


def paired(rev: str, rounds: int = 4, revolutions: float = 4.0) -> dict | None:
    """Step times of this checkout and of commit ``rev``, alternating run by run.

    Returns ``{dataset: (this checkout's times, rev's times, same final orientation)}`` (s),
    or None without git or without that commit.
    """
    tmp = tempfile.TemporaryDirectory()
    if baseline_tree(rev, tmp.name) is None:
        tmp.cleanup()
        return None
    env = dict(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    here, base = TreeWorker(__file__, ROOT, env), TreeWorker(__file__, Path(tmp.name), env)
    out = {}
    try:
        for name in DATASETS:
            got = {id(here): [], id(base): []}
            final = {}
            for r in range(rounds):
                for w in ((here, base) if r % 2 == 0 else (base, here)):
                    res = w.ask(dataset=name, revolutions=revolutions)
                    got[id(w)].append(res["times"])
                    final[id(w)] = res["orientation"]
            out[name] = (np.concatenate(got[id(here)]), np.concatenate(got[id(base)]),
                         bool(abs(final[id(here)] - final[id(base)]) < 1e-6))
    finally:
        here.close()
        base.close()
        tmp.cleanup()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev", nargs="?", help="the commit to compare with")
    ap.add_argument("--rounds", type=int, default=4, help="runs of each data set per tree")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        _worker()
        return 0
    if not a.rev:
        ap.error("give the commit to compare with")
    res = paired(a.rev, a.rounds)
    if res is None:
        print(f"no commit {a.rev!r} in this repository", file=sys.stderr)
        return 2
    rows = []
    for name, (t, b, same) in res.items():
        rows.append([name, f"{len(t)}", f"{np.median(t) * 1e3:.3f}", f"{np.percentile(t, 95) * 1e3:.3f}",
                     f"{np.median(b) * 1e3:.3f}", f"{np.percentile(b, 95) * 1e3:.3f}",
                     f"{np.median(b) / np.median(t):.2f}x", "yes" if same else "no"])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"OrientationTracker.step, this checkout against {a.rev}, {a.rounds} runs each, alternating "
          f"(load average {load:.1f} on {os.cpu_count()} cores at the end):\n")
    print(table(["data set", "steps", "median (ms)", "p95 (ms)", f"{a.rev} median (ms)", f"{a.rev} p95 (ms)",
                 "speed-up", "same final orientation (1e-6 rad)"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
