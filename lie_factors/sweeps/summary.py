"""A sweep's results per cell (graph, fraction, kind, method): the worst and the median over the
seeds, and how many cases said their rejection was uncertain (``robust_status``), as the tables
of docs/benchmarks.md, and a plot of them against the fraction.

A case that failed or ran past its timeout counts as failed: precision and recall 0, map
error infinite.
"""

from __future__ import annotations

import os
from typing import Any, Iterable

import numpy as np

__all__ = ["cells", "summary", "plot", "METRICS"]

#: The plotted figures: column → axis label.
METRICS = {"precision": "precision", "recall": "recall", "map_error": "map error [% of the diagonal]"}


def _rows(results) -> list[dict[str, Any]]:
    from .results import read_results, rows_of

    if isinstance(results, (str, os.PathLike)):
        return read_results(os.fspath(results))
    return rows_of(results)


def cells(rows: Iterable[dict[str, Any]], tuning: Iterable[int] = ()) -> dict[tuple, list[dict[str, Any]]]:
    """The rows by cell (graph, fraction, kind, method), in the order cells first appear; rows of
    the seeds in ``tuning`` left out."""
    tuning = set(tuning)
    out: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        if r["seed"] not in tuning:
            out.setdefault((r["graph"], r["fraction"], r["kind"], r["method"]), []).append(r)
    return out


def _failed(r: dict[str, Any]) -> bool:
    return r["status"] != "ok"


def _figure(r: dict[str, Any], column: str) -> float:
    """A row's figure, a failed case's as the worst (0; the map error infinite); NaN where the
    method does not reject closures."""
    if _failed(r):
        return float("inf") if column == "map_error" else 0.0
    value = r[column]
    return float("nan") if value is None else float(value)


def _pair(values: np.ndarray, worst, fmt: str, unit: str = "") -> str:
    if np.all(np.isnan(values)):
        return "–"
    return f"{format(worst(values), fmt)}{unit} / {format(np.nanmedian(values), fmt)}{unit}"


def summary(results, tuning: Iterable[int] = ()) -> str:
    """The worst and the median per cell of a sweep's ``results`` (a results file's path or rows), over
    the seeds not in ``tuning``: a Markdown table (``lie-factors sweep --summary RESULTS``)."""
    rows = _rows(results)
    tuning = sorted(set(tuning))
    lines = [f"# worst and median over the seeds{f' (tuning seeds {tuning} left out)' if tuning else ''}; "
             "failed cases and those past the timeout count as failed in precision, recall and map error",
             "| graph | false | kind | method | seeds | precision worst / median | recall worst / median | "
             "map error / diag worst / median | seconds worst / median | uncertain |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    # cells in reading order (graph, kind, fraction, method), whatever order the cases finished in
    ordered = sorted(cells(rows, tuning).items(), key=lambda item: (item[0][0], item[0][2], item[0][1], item[0][3]))
    for (graph, fraction, kind, method), rs in ordered:
        seeds = ",".join(str(s) for s in sorted(r["seed"] for r in rs))
        failed = [r for r in rs if _failed(r)]
        pr = np.array([_figure(r, "precision") for r in rs])
        rc = np.array([_figure(r, "recall") for r in rs])
        mp = np.array([_figure(r, "map_error") for r in rs])
        sec = np.array([np.nan if r["seconds"] is None else r["seconds"] for r in rs])
        timeouts = sum(r["status"] == "timeout" for r in rs)
        over = []
        if timeouts:
            over.append(f"{timeouts} past the timeout")
        if len(failed) > timeouts:
            over.append(f"{len(failed) - timeouts} failed")
        note = f" ({', '.join(over)})" if over else ""
        lines.append(f"| {graph} | {fraction:.0%} | {kind} | {method}{note} | {seeds} | "
                     f"{_pair(pr, np.nanmin, '.3f')} | {_pair(rc, np.nanmin, '.3f')} | "
                     f"{_pair(mp, np.nanmax, '.3g', ' %')} | {_pair(sec, np.nanmax, '.2f')} | {_uncertain(rs)} |")
    return "\n".join(lines)


def _uncertain(rows: list[dict[str, Any]]) -> str:
    """"k of n": the cases that said ``uncertain`` among the n that ran to a robust status, the
    failed ones apart (they have none); "–" where no case reports one (a method without rejection,
    or rows written before the status was recorded)."""
    said = [r["robust_status"] for r in rows if not _failed(r) and r.get("robust_status")]
    if not said:
        return "–"
    return f"{sum(s.startswith('uncertain') for s in said)} of {len(said)}"


def _role(method: str, rows: list[dict[str, Any]]) -> str:
    """A method's plot role: ``native`` for GTSAM's backend, ``ours`` otherwise."""
    import json

    options = json.loads(rows[0]["options"] or "{}")
    return "native" if options.get("backend") == "native" else "ours"


def plot(results, path: str, tuning: Iterable[int] = ()) -> None:
    """Draw precision, recall and the map error (rows) against the fraction of false closures, one
    column per kind, one line per graph and method (the median; the worst as markers), each method
    in its role's style (:data:`lie_factors.app.plotting.STYLES`: ``ours``, GTSAM's ``native``);
    written atomically to ``path`` as PNG (``lie-factors sweep --summary RESULTS --plot FILE.png``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ..app.plotting import style
    from ..errors import InputError
    from ..util.atomic import check_writable, replace_atomically

    rows = [r for r in _rows(results) if r["kind"] != "clean"]
    if not rows:
        raise InputError("plot: no case with false closures to plot against the fraction")
    check_writable(path)
    by_cell = cells(rows, tuning)
    kinds = list(dict.fromkeys(k for (_, _, k, _) in by_cell))
    lines = list(dict.fromkeys((g, m) for (g, _, _, m) in by_cell))
    roles = {m: _role(m, rs) for (_, _, _, m), rs in by_cell.items()}
    graphs = list(dict.fromkeys(g for g, _ in lines))
    markers = "os^Dv<>pP*"
    fig = Figure(figsize=(4.2 * len(kinds) + 1.5, 9.5))
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(METRICS), len(kinds), squeeze=False, sharex=True)
    for col, kind in enumerate(kinds):
        for row, (column, label) in enumerate(METRICS.items()):
            ax = axes[row][col]
            for graph, method in lines:
                fractions = sorted(f for (g, f, k, m) in by_cell if (g, k, m) == (graph, kind, method))
                if not fractions:
                    continue
                values = [np.array([_figure(r, column) for r in by_cell[(graph, f, kind, method)]]) for f in fractions]
                if all(np.all(np.isnan(v)) for v in values):
                    continue
                worst = np.nanmax if column == "map_error" else np.nanmin
                kw = dict(style(roles[method]))
                marker = markers[graphs.index(graph) % len(markers)]
                x = 100 * np.array(fractions)
                ax.plot(x, [np.nanmedian(v) for v in values], marker=marker, label=f"{graph}: {method}", **kw)
                ax.plot(x, [worst(v) for v in values], marker=marker, ls="none", mfc="none",
                        color=kw.get("color"), alpha=0.7)
            if column == "map_error":
                ax.set_yscale("log")
            else:
                ax.set_ylim(-0.05, 1.05)
            if row == 0:
                ax.set_title(kind)
            if col == 0:
                ax.set_ylabel(label)
            if row == len(METRICS) - 1:
                ax.set_xlabel("false closures [% of the true ones]")
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", ncol=min(4, len(handles)))
    fig.suptitle("median (line) and worst (open markers) over the seeds")
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    replace_atomically(path, lambda tmp: fig.savefig(tmp, format="png", dpi=90), suffix=".png")
