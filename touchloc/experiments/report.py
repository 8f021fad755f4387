"""Standard plots and a markdown table from a results file.

A localisation sweep's rows give success, time and error per estimator and contact count
(:func:`markdown_table`, :func:`plot_results`); an orientation-tracking sweep's
(``kind = "dnf"``) give the right side count per cell, object and estimator
(:func:`dnf_markdown_table`, :func:`plot_dnf_results`). :func:`write_report` picks by the
rows' kind.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .runner import read_results, summarize

__all__ = ["markdown_table", "plot_results", "dnf_markdown_table", "plot_dnf_results", "write_report"]

#: right count of the DNF goal (seed 000's experiment; docs/dnf.md): a cell passes with every
#: object at this or more
DNF_GOAL = 0.9


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

    from .._validate import as_path
    from ..errors import ValidationError

    path = as_path(path, "path", must_exist=False)
    if hasattr(rows, "__iter__") and not isinstance(rows, (str, bytes, dict)):
        rows = list(rows)
    # the same checks as the table's (columns and numbers), and at least one row
    if not summarize(rows, by=("mode", "estimator", "planner", "region", "options", "contacts")):
        raise ValidationError("rows is empty: no trials to plot")
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
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise ValidationError(f"cannot write the plots {path}: {exc}") from None
    finally:
        plt.close(fig)


def _dnf_cell(r) -> tuple:
    return (r["normals_per_contact"], r["noise_deg"], r["drop"], r["bias_lo"], r["bias_hi"], r["slip_deg"])


def _dnf_cell_label(c) -> str:
    n, noise, drop, lo, hi, slip = c
    bias = f"{100 * lo:g} %" if lo == hi else f"{100 * lo:g}-{100 * hi:g} %"
    return f"{n} / {noise:g} / {100 * drop:g}% / {bias} / {slip:g}"


def _object_label(n: int) -> str:
    return "round" if n == 0 else f"{n}-gon"


def _dnf_grid(rows) -> tuple:
    """(estimators, cells, objects, right[e, c, o], sets[e, c, o]): the mean right count of
    each estimator, cell and object over its data sets (NaN where none ran). Estimators in
    the order of :data:`~touchloc.experiments.DNF_ESTIMATORS`, cells in the sweep's order
    (its ``cell`` index), objects by their number of sides, round last."""
    from .sweep import DNF_ESTIMATORS

    order = {}
    for r in rows:
        c = _dnf_cell(r)
        order[c] = min(order.get(c, r["cell"]), r["cell"])
    cells = sorted(order, key=lambda c: (order[c], c))
    known = list(DNF_ESTIMATORS)
    est = sorted({r["estimator"] for r in rows}, key=lambda e: (known.index(e) if e in known else len(known), e))
    objects = sorted({r["sides"] for r in rows}, key=lambda n: (n == 0, n))
    total = np.zeros((len(est), len(cells), len(objects)))
    sets = np.zeros_like(total)
    for r in rows:
        k = (est.index(r["estimator"]), cells.index(_dnf_cell(r)), objects.index(r["sides"]))
        total[k] += r["accuracy"]
        sets[k] += 1
    right = np.where(sets > 0, total / np.maximum(sets, 1), np.nan)
    return est, cells, objects, right, sets


_DNF_NUMBERS = ("sides", "normals_per_contact", "noise_deg", "drop", "bias_lo", "bias_hi", "slip_deg", "cell",
                "accuracy")


def _check_dnf_rows(rows) -> list:
    """The rows as a list, checked: dicts of an orientation-tracking sweep (``kind`` "dnf")
    with the columns the report reads."""
    from ..errors import ValidationError

    if isinstance(rows, (str, bytes, dict)) or not hasattr(rows, "__iter__"):
        raise ValidationError(f"rows must be a list of result dicts (read_results), got {type(rows).__name__}")
    rows = list(rows)
    if not rows:
        raise ValidationError("rows is empty: no trials to report")
    for i, r in enumerate(rows):
        if not isinstance(r, dict):
            raise ValidationError(f"rows[{i}] must be a result dict, got {type(r).__name__}")
        if r.get("kind") != "dnf":
            raise ValidationError(f"rows[{i}] is not an orientation-tracking trial (kind 'dnf'), got kind "
                                  f"{str(r.get('kind'))[:40]!r}")
        missing = [c for c in (*_DNF_NUMBERS, "estimator") if c not in r]
        if missing:
            raise ValidationError(f"rows[{i}] lacks columns {missing}")
        for c in _DNF_NUMBERS:
            v = r[c]
            if isinstance(v, (bool, str, bytes)) or not isinstance(v, (int, float, np.number)) or not np.isfinite(v):
                raise ValidationError(f"rows[{i}][{c!r}] must be a finite number, got {str(v)[:40]!r}")
        if not isinstance(r["estimator"], str):
            raise ValidationError(f"rows[{i}]['estimator'] must be a str, got {type(r['estimator']).__name__}")
    return rows


def dnf_markdown_table(rows) -> str:
    """Right side count per cell (rows) and object (columns), one table per estimator.

    Cells are labelled "normals per finger / noise (deg) / dropped / odometry bias / slip
    (deg)"; an entry is the mean over the data sets of the fraction of second-half samples
    with the right count. Under each table: how many cells have every object at 90 % or
    more (seed 000's goal, :data:`DNF_GOAL`).
    """
    est, cells, objects, right, sets = _dnf_grid(_check_dnf_rows(rows))
    out = []
    for e, name in enumerate(est):
        head = ["cell"] + [_object_label(n) for n in objects] + ["data sets"]
        out += [f"**{name}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for c, cell in enumerate(cells):
            vals = [("-" if np.isnan(v) else f"{100 * v:.0f} %") for v in right[e, c]]
            n = sets[e, c][sets[e, c] > 0]
            runs = "-" if n.size == 0 else (f"{n.min():.0f}" if n.min() == n.max() else f"{n.min():.0f}-{n.max():.0f}")
            out.append("| " + " | ".join([_dnf_cell_label(cell)] + vals + [runs]) + " |")
        ok = sum(bool(np.all(right[e, c][~np.isnan(right[e, c])] >= DNF_GOAL)) for c in range(len(cells)))
        out += ["", f"Every object at {100 * DNF_GOAL:.0f} % or more in {ok} of {len(cells)} cells.", ""]
    return "\n".join(out).rstrip() + "\n"


def plot_dnf_results(rows, path) -> None:
    """A heat map per estimator: the right side count per cell (rows) and object (columns),
    each entry written in; entries below 90 % in bold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._validate import as_path
    from ..errors import ValidationError

    path = as_path(path, "path", must_exist=False)
    est, cells, objects, right, _ = _dnf_grid(_check_dnf_rows(rows))
    ncol = min(len(est), 4)
    nrow = -(-len(est) // ncol)
    w = 1.0 + 0.75 * len(objects)
    fig, axes = plt.subplots(nrow, ncol, figsize=(2.6 + w * ncol, 1.2 + 0.32 * len(cells) * nrow), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        if i >= len(est):
            ax.set_visible(False)
            continue
        im = ax.imshow(100 * right[i], vmin=0, vmax=100, cmap="viridis", aspect="auto")
        for (c, o), v in np.ndenumerate(right[i]):
            if not np.isnan(v):
                ax.text(o, c, f"{100 * v:.0f}", ha="center", va="center", fontsize=8,
                        color="white" if v < 0.6 else "black", fontweight="bold" if v < DNF_GOAL else "normal")
        ax.set_xticks(range(len(objects)), [_object_label(n) for n in objects], fontsize=8)
        ax.set_yticks(range(len(cells)), [_dnf_cell_label(c) for c in cells] if i % ncol == 0 else [], fontsize=8)
        ax.set_title(est[i], fontsize=10)
        if i % ncol == 0:
            ax.set_ylabel("normals / noise (deg) / dropped / bias / slip (deg)", fontsize=8)
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="right side count, 2nd half (%)")
    try:
        fig.savefig(path, dpi=110, bbox_inches="tight")
    except OSError as exc:
        raise ValidationError(f"cannot write the heat map {path}: {exc}") from None
    finally:
        plt.close(fig)


def write_report(results, out_dir=None) -> tuple:
    """Write ``<stem>.md`` (table) and ``<stem>.png`` (plots) beside ``results`` or in ``out_dir``.

    ``results`` is a results CSV of :func:`~touchloc.experiments.run_sweep`. A localisation
    sweep gets success, time and error per estimator and contact count; an
    orientation-tracking sweep (``kind = "dnf"``) gets the right side count per cell and
    object, a table and a heat map per estimator.

    Raises
    ------
    ValidationError
        If the file is missing, holds no result rows, mixes sweep kinds or lacks their
        columns, or the report cannot be written.

    Returns
    -------
    (markdown path, png path)
    """
    from .._validate import as_path
    from ..errors import ValidationError
    from .runner import COLUMNS
    from .trial import DNF_COLUMNS

    results = as_path(results, "results")
    rows = read_results(results)
    if not rows:
        raise ValidationError(f"{results}: no result rows (is it a sweep's CSV?)")
    kinds = {r.get("kind", "localization") for r in rows}
    if len(kinds) > 1:
        raise ValidationError(f"{results}: rows of several sweep kinds ({', '.join(sorted(map(str, kinds)))}); "
                              "write each kind's sweep to its own file")
    dnf = kinds == {"dnf"}
    missing = [c for c in (DNF_COLUMNS if dnf else COLUMNS) if c not in rows[0]]
    if missing:
        raise ValidationError(f"{results}: not the results of a {'DNF ' if dnf else ''}sweep: no columns {missing[:6]}")
    d = results.parent if out_dir is None else as_path(out_dir, "out_dir", must_exist=False)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValidationError(f"cannot make the report's folder {d}: {exc}") from None
    md, png = d / (results.stem + ".md"), d / (results.stem + ".png")
    try:
        return _write_dnf(rows, results, md, png) if dnf else _write_localization(rows, results, md, png)
    except OSError as exc:
        raise ValidationError(f"cannot write the report in {d}: {exc}") from None


def _write_dnf(rows, results, md, png) -> tuple:
    plot_dnf_results(rows, png)
    md.write_text(f"# Orientation-tracking sweep: {results.name}\n\n{len(rows)} trials. Right side count in the "
                  f"second half of each run, the mean over the data sets.\n\n{dnf_markdown_table(rows)}\n"
                  f"![right count per cell and object]({png.name})\n")
    return md, png


def _write_localization(rows, results, md, png) -> tuple:
    plot_results(rows, png)
    md.write_text(f"# Sweep results: {results.name}\n\n{len(rows)} trials.\n\n{markdown_table(rows)}\n\n"
                  f"![plots]({png.name})\n")
    return md, png
