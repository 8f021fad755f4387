"""Helpers shared by the benchmark modules."""

from __future__ import annotations

import time
import warnings

import numpy as np


def timeit(fn, *, repeat: int = 3, min_time: float = 0.2):
    """Best wall time (s) of ``fn()`` over ``repeat`` rounds (each >= min_time total)."""
    best = np.inf
    for _ in range(repeat):
        n = 0
        t0 = time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= min_time:
                break
        best = min(best, dt / n)
    return best


def table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(str(x) for x in r) + " |")
    return "\n".join(out)


def quiet_load(name):
    from touchloc.data import load_object

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_object(name)


def big_bunny():
    """The bundled bunny (15 cm) subdivided twice: ~14k faces; three times: ~58k."""
    import trimesh

    from touchloc.models import MeshObject

    b = quiet_load("bunny")
    v, f = b.mesh.vertices, b.mesh.faces
    for _ in range(3):
        v, f = trimesh.remesh.subdivide(v, f)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MeshObject(trimesh.Trimesh(v, f), name="bunny-58k")
