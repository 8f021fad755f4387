"""Figures of an active-localisation run: a matplotlib summary and a 3-D HTML view."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["plot_run", "write_html", "html_page"]


def _touch_segments(result):
    segs = []
    for s in result.steps[1:]:
        for r in s.results:
            a, b = r.swept_segment
            c = None if r.contact is None else r.contact.points[0].tolist()
            segs.append({"a": a.tolist(), "b": b.tolist(), "hit": bool(r.hit), "c": c, "step": s.index})
    return segs


def plot_run(path, result, obj, *, title: str = "") -> Path:
    """Write a PNG: entropy and ADD-S per touch, and a top view of the final state.

    Parameters
    ----------
    path : str or Path
    result : ActiveResult
    obj : MeshObject
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    from matplotlib.ticker import MaxNLocator

    k = [s.index for s in result.steps]
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6))
    ax[0].plot(k, [s.entropy for s in result.steps], "o-")
    ax[0].set_xlabel("touch")
    ax[0].set_ylabel("belief entropy (nats)")
    ax[0].set_title("uncertainty")
    ax[1].semilogy(k, [max(s.error, 1e-5) * 1e3 for s in result.steps], "o-", label="true ADD-S of MAP")
    ax[1].semilogy(k, [max(s.expected_error, 1e-5) * 1e3 for s in result.steps], "s--", label="belief's expected ADD-S")
    ax[1].axhline(5.0, color="gray", lw=0.8, ls=":", label="5 mm")
    ax[1].set_xlabel("touch")
    ax[1].set_ylabel("mm")
    ax[1].legend(fontsize=8)
    ax[1].set_title("error")
    for axis in ax[:2]:
        axis.xaxis.set_major_locator(MaxNLocator(integer=True))
    a = ax[2]
    pts, _, _ = obj.sample_surface(1500, rng=0)
    if result.true_pose is not None:
        T = result.true_pose
        q = pts @ T[:3, :3].T + T[:3, 3]
        a.scatter(q[:, 0] * 1e3, q[:, 1] * 1e3, s=2, c="0.6", label="object (true pose)")
    T = result.steps[-1].map_pose
    q = pts[:400] @ T[:3, :3].T + T[:3, 3]
    a.scatter(q[:, 0] * 1e3, q[:, 1] * 1e3, s=2, c="tab:green", label="object (MAP estimate)")
    P = result.belief.poses[:, :3, 3]
    a.scatter(P[:, 0] * 1e3, P[:, 1] * 1e3, s=6, c="navy", alpha=0.5, zorder=3, label="particles (object origin)")
    for sgm in _touch_segments(result):
        A, B = np.array(sgm["a"]) * 1e3, np.array(sgm["b"]) * 1e3
        a.plot([A[0], B[0]], [A[1], B[1]], "-", color="tab:red" if sgm["hit"] else "tab:orange", lw=0.8)
        if sgm["c"] is not None:
            a.plot(sgm["c"][0] * 1e3, sgm["c"][1] * 1e3, "k.", ms=5)
        a.annotate(str(sgm["step"]), A[:2], fontsize=7)
    a.set_aspect("equal")
    ctr = (result.true_pose if result.true_pose is not None else T)[:2, 3] * 1e3
    reach = (np.linalg.norm(result.belief.region.half_extent) if result.belief.region is not None else 0.05) \
        + obj.radius + 0.03
    a.set_xlim(ctr[0] - reach * 1e3, ctr[0] + reach * 1e3)
    a.set_ylim(ctr[1] - reach * 1e3, ctr[1] + reach * 1e3)
    a.set_xlabel("x (mm)")
    a.set_ylabel("y (mm)")
    a.set_title("top view (red: hits, orange: misses)")
    a.legend(fontsize=7, loc="upper right", markerscale=3)
    return finish_figure(fig, path, title)


def finish_figure(fig, path, title=None):
    """Title, lay out, save at the library's resolution and close a matplotlib figure."""
    import matplotlib.pyplot as plt

    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


_PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>%(title)s</title>
<style>body{font-family:sans-serif;margin:12px;background:#fafafa}canvas{border:1px solid #ccc;background:#fff}
.k span{display:inline-block;margin-right:14px}</style></head>
<body><h3>%(title)s</h3>
<div class="k">%(legend)s</div>
<canvas id="c" width="760" height="560"></canvas>
<p>Drag to rotate; the view spins until you do. Units: mm. %(note)s</p>
<script>
const D = %(data)s;
const cv = document.getElementById('c'), g = cv.getContext('2d');
let yaw = 0.6, pitch = -0.5, spin = true, drag = null;
const ctr = D.center, sc = 0.42 * Math.min(cv.width, cv.height) / D.extent;
function proj(p) {
  const x = p[0] - ctr[0], y = p[1] - ctr[1], z = p[2] - ctr[2];
  const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
  const x1 = cy * x - sy * y, y1 = sy * x + cy * y;
  const y2 = cp * y1 - sp * z, z2 = sp * y1 + cp * z;
  return [cv.width / 2 + sc * x1, cv.height / 2 - sc * z2, y2];
}
%(draw)s
cv.onmousedown = e => { drag = [e.clientX, e.clientY]; spin = false; };
window.onmouseup = () => drag = null;
cv.onmousemove = e => { if (!drag) return; yaw += (e.clientX - drag[0]) * 0.01; pitch += (e.clientY - drag[1]) * 0.01; drag = [e.clientX, e.clientY]; draw(); };
function tick() { if (spin) { yaw += 0.01; draw(); } requestAnimationFrame(tick); }
draw(); tick();
</script>
<pre>%(table)s</pre>
</body></html>
"""


def html_page(path, *, title: str, legend: str, data: dict, draw_js: str, table: str = "", note: str = "") -> Path:
    """Write a self-contained HTML page with a rotating 3-D canvas view (plain JS).

    ``data`` (JSON-able, coordinates in mm) must hold ``center`` (3,) and ``extent``;
    ``draw_js`` defines ``function draw()`` using ``g`` (the 2-D context), ``proj(p)``
    (-> [x, y, depth] on the canvas) and ``D`` (the data). ``legend`` is trusted HTML.
    """
    import html

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(_PAGE % {"title": html.escape(title), "legend": legend, "data": json.dumps(data),
                             "draw": draw_js, "table": html.escape(table), "note": html.escape(note)})
    return path


_LEGEND = ('<span style="color:#999">&#9679; object at the true pose</span><span style="color:#2a2">&#9679; MAP '
           'estimate</span>\n<span style="color:#36c">&#9679; particles</span><span style="color:#d22">&#8212; touch '
           'that hit</span>\n<span style="color:#e90">&#8212; touch that missed</span><span>&#9679; contacts</span>')

_DRAW = """function dots(pts, col, r) { g.fillStyle = col; for (const p of pts) { const q = proj(p); g.fillRect(q[0] - r / 2, q[1] - r / 2, r, r); } }
function draw() {
  g.clearRect(0, 0, cv.width, cv.height);
  dots(D.truth, '#aaa', 2); dots(D.map, '#2a2', 2); dots(D.particles, 'rgba(50,100,200,0.5)', 2);
  for (const s of D.touches) {
    const a = proj(s.a), b = proj(s.b);
    g.strokeStyle = s.hit ? '#d22' : '#e90'; g.lineWidth = 1.2; g.beginPath(); g.moveTo(a[0], a[1]); g.lineTo(b[0], b[1]); g.stroke();
    g.fillStyle = '#000'; g.font = '10px sans-serif'; g.fillText(s.step, a[0] + 3, a[1] - 3);
    if (s.c) { const c = proj(s.c); g.beginPath(); g.arc(c[0], c[1], 3, 0, 6.3); g.fill(); }
  }
}"""


def write_html(path, result, obj, *, title: str = "Active tactile localisation", n_points: int = 1200) -> Path:
    """Write a self-contained HTML page with a rotating 3-D view (plain JS canvas).

    Shows the object at the true and the estimated pose, the final particles and every
    touch (swept segment and contact), plus the per-touch table.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    pts, _, _ = obj.sample_surface(n_points, rng=0)
    mm = lambda a: np.round(np.asarray(a) * 1e3, 2).tolist()  # noqa: E731
    T = result.steps[-1].map_pose
    truth = result.true_pose if result.true_pose is not None else T
    P = result.belief.poses
    sel = np.linspace(0, len(P) - 1, min(len(P), 400)).astype(int)
    segs = _touch_segments(result)
    for s in segs:
        s["a"], s["b"] = mm(s["a"]), mm(s["b"])
        s["c"] = None if s["c"] is None else mm(s["c"])
    truth_pts = pts @ truth[:3, :3].T + truth[:3, 3]
    data = {"truth": mm(truth_pts), "map": mm(pts[: n_points // 2] @ T[:3, :3].T + T[:3, 3]),
            "particles": mm(P[sel, :3, 3]), "touches": segs,
            "center": mm(truth_pts.mean(axis=0)),
            "extent": float(max(np.ptp(truth_pts, axis=0).max(), 1e-3) * 1e3 * 2.6)}
    return html_page(path, title=title, legend=_LEGEND, data=data, draw_js=_DRAW, table=result.table())
