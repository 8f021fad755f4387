"""Standard plots and a markdown table from a results file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .runner import read_results, summarize

__all__ = ["markdown_table", "plot_results", "write_report"]


def _label(r) -> str:
    where = "" if r["region"] == "full" else f" ({r['region']})"
    if r["mode"] == "active":
        return f"active {r['planner']}{where}"
    if r["mode"] == "identify":
        return f"identify (success: the right mesh){where}"
    return r["estimator"] + ("" if r["options"] in ("", "{}") else f" {r['options']}") + where


def markdown_table(rows) -> str:
    """One line per (mode, estimator, planner, region, mesh, contacts): success, ADD-S, time, touches, coverage.

    The mesh cell names the region when it is not "full".
    """
    head = ("mode", "estimator", "mesh", "contacts", "trials", "success", "median ADD-S (mm)", "median time (s)",
            "median touches", "coverage 50 / 90 / 95 %")
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summarize(rows, by=("mode", "estimator", "planner", "region", "mesh", "contacts")):
        est = s["estimator"] + (f" + {s['planner']}" if s["planner"] else "")
        mesh = s["mesh"] + ("" if s["region"] == "full" else f" ({s['region']})")
        out.append("| " + " | ".join([
            s["mode"], est, mesh, str(s["contacts"]), str(s["trials"]), f"{100 * s['success']:.0f} %",
            f"{1e3 * s['median_add_s']:.2f}", f"{s['median_time']:.2f}", f"{s['median_touches']:.0f}",
            f"{100 * s['cov50']:.0f} / {100 * s['cov90']:.0f} / {100 * s['cov95']:.0f}"]) + " |")
    return "\n".join(out)


def plot_results(rows, path) -> None:
    """Three panels: success vs contacts, time vs contacts (per estimator, over meshes), ADD-S CDFs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict = {}
    for r in rows:
        groups.setdefault(_label(r), []).append(r)
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    cmap = plt.get_cmap("tab10")
    for i, (lab, g) in enumerate(sorted(groups.items())):
        color = cmap(i % 10)
        ks = sorted({r["contacts"] for r in g})
        succ = [np.mean([r["success"] for r in g if r["contacts"] == k]) for k in ks]
        tm = [np.median([r["time"] for r in g if r["contacts"] == k]) for k in ks]
        axes[0].plot(ks, 100 * np.array(succ), "o-", color=color, label=lab)
        axes[1].plot(ks, tm, "o-", color=color, label=lab)
        e = np.sort([1e3 * r["add_s"] for r in g])
        axes[2].step(e, np.arange(1, len(e) + 1) / len(e), where="post", color=color, label=lab)
    axes[0].set(xlabel="contacts (passive) / touch budget (active)", ylabel="success (%)", ylim=(-3, 103),
                title="success (ADD-S below threshold)")
    axes[1].set(xlabel="contacts (passive) / touch budget (active)", ylabel="median time (s)",
                title="time per trial")
    axes[1].set_yscale("log")
    axes[2].set(xlabel="ADD-S of the MAP pose (mm)", ylabel="fraction of trials", ylim=(0, 1.02),
                title="error CDF (all meshes and contacts)")
    axes[2].set_xscale("log")
    for ax in axes:
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(results, out_dir=None) -> tuple:
    """Write ``<stem>.md`` (table) and ``<stem>.png`` (plots) beside ``results`` or in ``out_dir``.

    Returns
    -------
    (markdown path, png path)
    """
    results = Path(results)
    rows = read_results(results)
    if not rows:
        from ..errors import ValidationError

        raise ValidationError(f"{results}: no result rows (is it a sweep's CSV?)")
    d = Path(out_dir) if out_dir else results.parent
    d.mkdir(parents=True, exist_ok=True)
    md, png = d / (results.stem + ".md"), d / (results.stem + ".png")
    plot_results(rows, png)
    md.write_text(f"# Sweep results: {results.name}\n\n{len(rows)} trials.\n\n{markdown_table(rows)}\n\n"
                  f"![plots]({png.name})\n")
    return md, png
