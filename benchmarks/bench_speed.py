"""Localisation speed with few contacts, against the code of a baseline commit.

The README quick-start path (``ProximityModel(obj, 0.002, np.deg2rad(5))``,
``ScalingSeries(model, rng=seed).localize``), a hidden pose uniform in a 400 mm cube with
uniform rotation, k contacts with 2 mm / 5 deg noise. Two worker processes run the same
trials: one imports touchloc from this checkout, the other from a ``git archive`` of the
baseline commit. Trials alternate between the two, so both see the same machine load;
the table reports per-trial time ratios (baseline / current).

Run directly for one worker (``python benchmarks/bench_speed.py --worker``, reading JSON
trial requests on stdin) or through ``benchmarks/run.py --only speed``. The environment
variable ``TOUCHLOC_BENCH_THREADS`` sets the worker threads (numba; default: all cores).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

TITLE = "Localisation speed with few contacts (vs. the baseline commit)"

BASELINE = "f4e652e"
ROOT = Path(__file__).resolve().parent.parent
#: meshes whose profile guided the work, and meshes held out from it
TUNED = ["mug", "milk"]
HELD_OUT = ["can", "lemon", "bread", "cereal"]


# -- worker side -------------------------------------------------------------------------
def _trial(obj, region, k, seed):
    from touchloc.models import Contacts

    rng = np.random.default_rng(seed)
    true = region.sample(1, rng=rng)[0]
    p, n, _ = obj.sample_surface(k, rng=rng)
    p = p + rng.normal(scale=0.002, size=p.shape)
    n = n + rng.normal(scale=np.radians(5) / np.sqrt(2), size=n.shape)
    return true, Contacts(p, n).transform(true)


def worker() -> int:
    warnings.simplefilter("ignore")
    from touchloc.belief import PoseRegion, ScalingSeries, add_s, identify
    from touchloc.data import load_object
    from touchloc.models import ProximityModel

    cube = PoseRegion.box((0, 0, 0), 0.2, "full")
    models = {}

    def model(name):
        if name not in models:
            models[name] = ProximityModel(load_object(name), 0.002, np.deg2rad(5))
            _, c = _trial(models[name].obj, cube, 30, 0)  # compile kernels, build grids
            ScalingSeries(models[name], rng=0, progress=False).localize(c, cube)
        return models[name]

    import touchloc

    print(json.dumps({"ready": True, "touchloc": touchloc.__file__}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        if req.get("kind") == "identify":
            ms = {n: model(n) for n in req["meshes"]}
            region = PoseRegion.box((0, 0, 0), 0.1, "full")
            true, c = _trial(ms[req["truth"]].obj, region, req["k"], req["seed"])
            t0 = time.perf_counter()
            post = identify(ms, c, region, rng=req["seed"])
            dt = time.perf_counter() - t0
            print(json.dumps({"time": dt, "correct": max(post, key=post.get) == req["truth"]}), flush=True)
            continue
        m = model(req["mesh"])
        true, c = _trial(m.obj, cube, req["k"], req["seed"])
        t0 = time.perf_counter()
        b = ScalingSeries(m, rng=req["seed"], progress=False).localize(c, cube)
        dt = time.perf_counter() - t0
        print(json.dumps({"time": dt, "adds": float(add_s(m.obj, b.map_pose(), true)),
                          "evaluations": int(b.info.get("evaluations", 0))}), flush=True)
    return 0


# -- driver side -------------------------------------------------------------------------
class _Worker:
    def __init__(self, path: Path, threads: int | None):
        env = dict(os.environ, PYTHONPATH=str(path), PYTHONWARNINGS="ignore")
        if threads:
            env["NUMBA_NUM_THREADS"] = str(threads)
        self.p = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"], cwd=str(path),
                                  env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        hello = json.loads(self.p.stdout.readline())
        if not Path(hello["touchloc"]).resolve().is_relative_to(path.resolve()):
            raise RuntimeError(f"benchmark worker imported {hello['touchloc']}, not the tree under {path}")

    def ask(self, **req):
        self.p.stdin.write(json.dumps(req) + "\n")
        self.p.stdin.flush()
        line = self.p.stdout.readline()
        if not line:
            raise RuntimeError("benchmark worker died")
        return json.loads(line)

    def close(self):
        self.p.stdin.close()
        self.p.wait(timeout=60)


def _baseline_tree(tmp: Path) -> Path | None:
    """The touchloc package of the baseline commit, unpacked under tmp (None without git)."""
    try:
        data = subprocess.run(["git", "-C", str(ROOT), "archive", BASELINE, "touchloc"],
                              check=True, capture_output=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    arch = tmp / "base.tar"
    arch.write_bytes(data)
    with tarfile.open(arch) as tf:
        tf.extractall(tmp / "base")
    return tmp / "base"


def _fmt_row(label, k, base, cur):
    tb = np.array([r["time"] for r in base]) if base else None
    tc = np.array([r["time"] for r in cur])
    sc = np.mean([r["adds"] < 0.005 for r in cur])
    row = [label, k, len(tc), f"{np.median(tc):.2f}", f"{np.percentile(tc, 95) / np.median(tc):.1f}",
           f"{100 * sc:.0f} %"]
    if base:
        sb = np.mean([r["adds"] < 0.005 for r in base])
        row += [f"{np.median(tb):.2f}", f"{100 * sb:.0f} %", f"{np.median(tb / tc):.1f}x",
                f"{np.median([r['evaluations'] for r in base]) / np.median([r['evaluations'] for r in cur]):.2f}"]
    return row


def run(quick: bool = False) -> str:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import table

    threads = int(os.environ.get("TOUCHLOC_BENCH_THREADS", "0")) or None
    seeds = 2 if quick else 3
    cases = [(m, k) for m in TUNED for k in (5, 10, 30)]
    cases += [(m, 10) for m in (HELD_OUT[:1] if quick else HELD_OUT[:2])]
    with tempfile.TemporaryDirectory() as tmpd:
        base_path = _baseline_tree(Path(tmpd))
        cur = _Worker(ROOT, threads)
        base = _Worker(base_path, threads) if base_path else None
        rows, load = [], [os.getloadavg()[0]]
        try:
            for mesh, k in cases:
                rb, rc = [], []
                for s in range(seeds):
                    seed = 5000 + 100 * k + s
                    if base:
                        rb.append(base.ask(mesh=mesh, k=k, seed=seed))
                    rc.append(cur.ask(mesh=mesh, k=k, seed=seed))
                label = mesh + ("" if mesh in TUNED else " (held out)")
                rows.append(_fmt_row(label, k, rb, rc))
        finally:
            cur.close()
            if base:
                base.close()
        load.append(os.getloadavg()[0])
    head = ["mesh", "contacts", "trials", "median s", "p95 / median", "ADD-S < 5 mm"]
    if base_path:
        head += [f"baseline {BASELINE} median s", "baseline ADD-S < 5 mm", "speed-up (median of per-trial ratios)",
                 "likelihood evaluations, baseline / current"]
    text = [
        "Hidden pose uniform in a 400 mm cube with uniform rotation; k contacts sampled over the "
        "surface with 2 mm / 5 deg noise; `ScalingSeries(ProximityModel(obj, 0.002, np.deg2rad(5)), "
        "rng=seed).localize` with default settings. Each trial runs in two worker processes, this "
        f"checkout and commit {BASELINE} (`git archive`), one after the other, so both see the same "
        f"load; kernels compiled and grids built before timing. Threads: "
        f"{threads or os.cpu_count()}. Load average (1 min) before / after: "
        f"{load[0]:.1f} / {load[-1]:.1f} on {os.cpu_count()} cores.",
        table(head, rows),
    ]
    return "\n\n".join(text)


if __name__ == "__main__":
    if "--worker" in sys.argv:
        sys.exit(worker())
    print(run(quick="--quick" in sys.argv))
