"""Run every benchmark and rewrite docs/benchmarks.md.

Each ``benchmarks/bench_*.py`` module defines ``TITLE`` and ``run(quick: bool) -> str``
returning a markdown section (tables of measured numbers, with ratios against a baseline
measured in the same run). Usage::

    python benchmarks/run.py            # full runs
    python benchmarks/run.py --quick    # small sizes, a few minutes
    python benchmarks/run.py --only models dnf
    python benchmarks/run.py --only localization --executor dask --workers 4

The localisation, planning and identification benchmarks are sweeps
(``touchloc.experiments``): their trials run on a process pool, one single-threaded
worker per core (``--executor``, ``--workers``), and their tidy rows go to
``out/bench/NAME.csv``; ``--resume`` continues an interrupted run from those files.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib.util
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
OUT = HERE.parent / "docs" / "benchmarks.md"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    mem = ""
    try:
        with open("/proc/meminfo") as fh:
            kb = int(fh.readline().split()[1])
            mem = f", {kb / 2**20:.0f} GiB"
    except (OSError, ValueError):
        pass
    import numpy

    return (f"{cpu}, {os.cpu_count()} cores{mem}; Python {platform.python_version()}, "
            f"numpy {numpy.__version__}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    ap.add_argument("--only", nargs="*", help="module suffixes to run (e.g. models dnf)")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--executor", default="processes",
                    help="how sweep benchmarks run their trials: processes (default), serial, dask, dask://HOST:PORT")
    ap.add_argument("--workers", type=int, default=None, help="sweep workers (default: all cores)")
    ap.add_argument("--resume", action="store_true",
                    help="keep the rows already in out/bench/*.csv (an interrupted run) instead of starting afresh")
    args = ap.parse_args(argv)
    # read by benchmarks/_common.py (the modules import it fresh below)
    os.environ["TOUCHLOC_BENCH_EXECUTOR"] = args.executor
    os.environ["TOUCHLOC_BENCH_WORKERS"] = str(args.workers or 0)
    os.environ["TOUCHLOC_BENCH_RESUME"] = "1" if args.resume else ""
    mods = sorted(HERE.glob("bench_*.py"))
    if args.only:
        mods = [m for m in mods if m.stem[len("bench_"):] in args.only]
    out = Path(args.out)
    new = {}
    for path in mods:
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        print(f"== {path.stem}", flush=True)
        t0 = time.perf_counter()
        body = mod.run(quick=args.quick)
        dt = time.perf_counter() - t0
        cmd = f"python benchmarks/run.py --only {path.stem[6:]}" + (" --quick" if args.quick else "")
        if args.executor != "processes" or args.workers:
            cmd += f" --executor {args.executor}" + (f" --workers {args.workers}" if args.workers else "")
        stamp = _dt.date.today().isoformat()
        new[path.stem] = (f"<!-- bench: {path.stem} -->\n## {mod.TITLE}\n\n_Measured {stamp} on {machine()}; "
                               f"`{cmd}` ({dt:.0f} s)._\n\n{body.strip()}\n")
        print(body, flush=True)
    # re-read the file now: other sections may have been rewritten while these ran
    sections = _existing_sections(out)
    sections.update(new)
    text = "# Benchmarks\n\nWritten by `make bench` (`python benchmarks/run.py`); each section says how it was measured.\n\n"
    text += "\n".join(sections[k].rstrip("\n") + "\n" for k in sorted(sections))  # one blank line between
    out.write_text(text)
    print(f"wrote {out}")
    return 0


def _existing_sections(path: Path) -> dict:
    """Keep sections of benchmarks not re-run this time (keyed by module name)."""
    if not path.exists():
        return {}
    out, key, buf = {}, None, []
    for line in path.read_text().splitlines(keepends=True):
        if line.startswith("<!-- bench:"):
            if key:
                out[key] = "".join(buf)
            key, buf = line.split(":", 1)[1].split("-->")[0].strip(), [line]
        elif key:
            buf.append(line)
    if key:
        out[key] = "".join(buf)
    return out


if __name__ == "__main__":
    sys.exit(main())
