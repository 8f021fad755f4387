"""Figures of a shape map: a matplotlib summary and a rotating 3-D HTML view."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_map", "write_map_html", "plot_trajectory"]


def _segments(results):
    out = []
    for r in results:
        a, b = r.swept_segment
        out.append((a, b, r.hit))
    return out


def plot_map(path, run, truth=None, *, title: str = "", history=None) -> Path:
    """Write a PNG: the map's surface coloured by its uncertainty, with the contacts and
    the swept paths, the true surface beside it, and (if given) the error per touch.

    Parameters
    ----------
    path : str or Path
    run : ExplorationRun
    truth : MeshObject, optional
        The true object in the world frame.
    history : list of (touches, chamfer (m), fscore), optional
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import cm, colors

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    smap = run.map
    mesh = smap.to_mesh().mesh
    V, F = mesh.vertices, mesh.faces
    sd = smap.surface_std(mesh.triangles_center) * (1e3 if smap.method == "gpis" else 1.0)
    unit = "mm" if smap.method == "gpis" else ""
    n_panels = 2 + (history is not None) if truth is not None else 1 + (history is not None)
    fig = plt.figure(figsize=(5.2 * n_panels, 5.0))
    ax = fig.add_subplot(1, n_panels, 1, projection="3d")
    norm = colors.Normalize(vmin=0.0, vmax=max(float(np.percentile(sd, 98)), 1e-9))
    poly = ax.plot_trisurf(V[:, 0] * 1e3, V[:, 1] * 1e3, V[:, 2] * 1e3, triangles=F, linewidth=0,
                           antialiased=False, shade=False)
    poly.set_facecolor(cm.viridis(norm(sd)))
    P = smap.contacts.points * 1e3
    if len(P):
        ax.scatter(P[:, 0], P[:, 1], P[:, 2], c="red", s=8, depthshade=False, label="contacts")
    lo, hi = smap.lo * 1e3, smap.hi * 1e3
    for a, b, hit in _segments(run.results)[-60:]:
        a, b = a * 1e3, b * 1e3
        # draw the part of the path inside the box only
        t = np.linspace(0, 1, 40)[:, None]
        seg = a + t * (b - a)
        seg = seg[np.all((seg >= lo) & (seg <= hi), axis=1)]
        if len(seg) > 1:
            ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], color="tab:red" if hit else "tab:orange", lw=0.5, alpha=0.6)
    _equal_3d(ax, lo, hi)
    ax.set_title(f"map ({smap.method}), {run.touches} touches, {smap.n_contacts} contacts", fontsize=10)
    sm = cm.ScalarMappable(norm=norm, cmap="viridis")
    fig.colorbar(sm, ax=ax, shrink=0.6, pad=0.1, label=f"shape uncertainty {unit}".strip())
    k = 2
    if truth is not None:
        ax2 = fig.add_subplot(1, n_panels, 2, projection="3d")
        T = truth.mesh
        ax2.plot_trisurf(T.vertices[:, 0] * 1e3, T.vertices[:, 1] * 1e3, T.vertices[:, 2] * 1e3,
                         triangles=T.faces, color="0.7", linewidth=0)
        _equal_3d(ax2, lo, hi)
        ax2.set_title("true object (hidden)", fontsize=10)
        k = 3
    if history is not None:
        ax3 = fig.add_subplot(1, n_panels, k)
        h = np.array(history, dtype=float)
        ax3.plot(h[:, 0], h[:, 1] * 1e3, "o-", label="Chamfer distance (mm)")
        ax3.set_xlabel("touches")
        ax3.set_ylabel("Chamfer distance (mm)")
        ax3b = ax3.twinx()
        ax3b.plot(h[:, 0], h[:, 2], "s--", color="tab:green", label="F-score at 5 mm")
        ax3b.set_ylabel("F-score at 5 mm")
        ax3b.set_ylim(0, 1.02)
        ax3.set_title("accuracy against the true mesh", fontsize=10)
        lines = ax3.get_lines() + ax3b.get_lines()
        ax3.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="center right")
    for a in fig.axes:
        if hasattr(a, "set_zlabel"):
            a.set_xlabel("x (mm)", fontsize=8)
            a.set_ylabel("y (mm)", fontsize=8)
            a.set_zlabel("z (mm)", fontsize=8)
            a.tick_params(labelsize=7)
    return _finish(fig, path, title)


def _finish(fig, path, title):
    from ..planners.viz import finish_figure

    return finish_figure(fig, path, title)


def _equal_3d(ax, lo, hi):
    c, r = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))


_LEGEND = ('<span>map surface, coloured by uncertainty (blue: known, yellow: unknown)</span>\n'
           '<span style="color:#999">&#9679; true surface</span><span style="color:#d22">&#9679; contacts</span>\n'
           '<span style="color:#e90">&#8212; swept paths</span>')

_DRAW = """function draw() {
  g.clearRect(0, 0, cv.width, cv.height);
  g.fillStyle = '#bbb'; for (const p of D.truth) { const q = proj(p); g.fillRect(q[0] - 1, q[1] - 1, 2, 2); }
  for (let i = 0; i < D.map.length; i++) { const q = proj(D.map[i]); g.fillStyle = D.col[i]; g.fillRect(q[0] - 1.5, q[1] - 1.5, 3, 3); }
  g.strokeStyle = 'rgba(230,150,0,0.5)'; g.lineWidth = 1;
  for (const s of D.rays) { const a = proj(s[0]), b = proj(s[1]); g.beginPath(); g.moveTo(a[0], a[1]); g.lineTo(b[0], b[1]); g.stroke(); }
  g.fillStyle = '#d22'; for (const p of D.contacts) { const q = proj(p); g.beginPath(); g.arc(q[0], q[1], 3, 0, 6.3); g.fill(); }
}"""


def write_map_html(path, run, truth=None, *, title: str = "Shape map from touch", stats: str = "",
                   n_points: int = 2500) -> Path:
    """Write a self-contained HTML page with a rotating 3-D view of the map (plain JS canvas)."""
    from matplotlib import cm, colors

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    smap = run.map
    m = smap.to_mesh()
    pts, _, _ = m.sample_surface(n_points, rng=0)
    sd = smap.surface_std(pts)
    norm = colors.Normalize(0.0, max(float(np.percentile(sd, 98)), 1e-12))
    col = [colors.to_hex(c) for c in cm.viridis(norm(sd))]
    mm = lambda a: np.round(np.asarray(a) * 1e3, 2).tolist()  # noqa: E731
    lo, hi = smap.lo, smap.hi
    rays = []
    for a, b, _ in _segments(run.results)[-80:]:
        # clip to the box for the view
        t = np.linspace(0, 1, 60)[:, None]
        seg = a + t * (b - a)
        inb = np.all((seg >= lo) & (seg <= hi), axis=1)
        if inb.sum() > 1:
            rays.append([mm(seg[inb][0]), mm(seg[inb][-1])])
    tp = truth.sample_surface(1500, rng=1)[0] if truth is not None else np.zeros((0, 3))
    data = {"map": mm(pts), "col": col, "truth": mm(tp), "contacts": mm(smap.contacts.points), "rays": rays,
            "center": mm(0.5 * (lo + hi)), "extent": float(np.max(hi - lo) * 1e3 * 1.4)}
    from ..planners.viz import html_page

    return html_page(path, title=title, legend=_LEGEND, data=data, draw_js=_DRAW, table=run.table(), note=stats)


def plot_trajectory(path, estimated, true, *, obj=None, title: str = "") -> Path:
    """Write a PNG: the estimated against the true path of the object (top view) and the
    pose error per step (translation, rotation, and ADD-S when ``obj`` is given).

    Parameters
    ----------
    estimated, true : (T, 4, 4) float
        Pose trajectories (T_world_object), one per step.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    E, G = np.asarray(estimated, float), np.asarray(true, float)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.4))
    ax[0].plot(G[:, 0, 3] * 1e3, G[:, 1, 3] * 1e3, "-", color="0.5", label="true")
    ax[0].plot(E[:, 0, 3] * 1e3, E[:, 1, 3] * 1e3, "-", color="tab:blue", label="estimated")
    ax[0].plot(G[0, 0, 3] * 1e3, G[0, 1, 3] * 1e3, "ko", ms=4, label="start")
    ax[0].set_aspect("equal", adjustable="datalim")
    ax[0].set_xlabel("x (mm)")
    ax[0].set_ylabel("y (mm)")
    ax[0].set_title("object origin, top view")
    ax[0].legend(fontsize=8)
    k = np.arange(len(E))
    dt = np.linalg.norm(E[:, :3, 3] - G[:, :3, 3], axis=1) * 1e3
    tr = np.einsum("nij,nij->n", E[:, :3, :3], G[:, :3, :3])
    da = np.degrees(np.arccos(np.clip((tr - 1) / 2, -1, 1)))
    ax[1].plot(k, dt, label="translation error (mm)")
    if obj is not None:
        from ..belief import add_s

        ax[1].plot(k, [add_s(obj, a, b) * 1e3 for a, b in zip(E, G)], label="ADD-S (mm)")
    ax[1].set_xlabel("action")
    ax[1].set_ylabel("mm")
    ax2 = ax[1].twinx()
    ax2.plot(k, da, color="tab:red", alpha=0.6, label="rotation error (deg)")
    ax2.set_ylabel("deg")
    lines = ax[1].get_lines() + ax2.get_lines()
    ax[1].legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="upper left")
    ax[1].set_title("pose error per action")
    return _finish(fig, path, title)
