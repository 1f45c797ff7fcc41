"""Trajectory plots for the CLI (Agg only, no pyplot global state), and the positions they draw.

We draw on a bare ``matplotlib.figure.Figure`` with an Agg canvas, so the CLI
works headless and never changes the matplotlib backend a user has chosen.
matplotlib is imported by :func:`plot_trajectories` only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..posegraph.landmarks import landmark_keys, pose_keys

if TYPE_CHECKING:
    import gtsam

#: The style of each kind of series a plot draws (a series' role: by default its label), so that
#: every series is told apart from the others drawn with it.
STYLES = {
    "ground truth": dict(color="black", lw=1.5, ls="--"),
    "initial": dict(color="tab:red", lw=1.0, alpha=0.8),
    "optimized": dict(color="tab:blue", lw=1.2),
    "ours": dict(color="tab:blue", lw=1.2),
    "native": dict(color="tab:orange", lw=1.0, ls="-."),
    "initial landmarks": dict(color="tab:red", marker="x", s=12, alpha=0.6),
    "optimized landmarks": dict(color="tab:green", marker="o", s=10),
    "rejected loop closures": dict(color="tab:red", lw=0.6, alpha=0.7),
    "95% position ellipses": dict(color="tab:purple", lw=0.5, alpha=0.8),
}


def style(label: str, roles: dict[str, str] | None = None) -> dict:
    """The matplotlib keywords of the series ``label``: :data:`STYLES` of its role (``roles[label]``,
    or the label itself).  ``ValueError`` for a series with no style, which would otherwise take
    matplotlib's next colour, the same as another series'."""
    role = (roles or {}).get(label, label)
    if role not in STYLES:
        raise ValueError(f"no plot style for the series {label!r} (role {role!r}); known: {', '.join(STYLES)}")
    return STYLES[role]


def plot_trajectories(path: str, trajectories: dict[str, np.ndarray], title: str = "",
                      three_d: bool = True, points: dict[str, np.ndarray] | None = None,
                      segments: dict[str, np.ndarray] | None = None,
                      outlines: dict[str, np.ndarray] | None = None, roles: dict[str, str] | None = None) -> None:
    """Save a PNG of :func:`trajectory_figure` (same arguments); ``path`` is written as PNG
    whatever its suffix (callers write to a temporary name)."""
    fig = trajectory_figure(trajectories, title, three_d, points, segments, outlines, roles)
    fig.savefig(path, format="png", dpi=100)


def trajectory_figure(trajectories: dict[str, np.ndarray], title: str = "", three_d: bool = True,
                      points: dict[str, np.ndarray] | None = None, segments: dict[str, np.ndarray] | None = None,
                      outlines: dict[str, np.ndarray] | None = None, roles: dict[str, str] | None = None):
    """A figure of named trajectories, each an array of positions, shape (N, 3), of named point
    sets (landmarks), shape (M, 3), drawn as markers, of named sets of line segments (rejected
    loop closures), shape (K, 2, 3), and of named sets of closed curves in the top view
    (covariance ellipses), shape (K, N, 2); each series in the style of its role (:func:`style`).

    Left: top view (x, y).  Right (if ``three_d``): a 3-D view.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    for label in (*trajectories, *(points or {}), *(segments or {}), *(outlines or {})):
        style(label, roles)  # every series styled before anything is drawn
    fig = Figure(figsize=(12, 5.5) if three_d else (7, 6))
    FigureCanvasAgg(fig)
    top = fig.add_subplot(1, 2 if three_d else 1, 1)
    ax3 = fig.add_subplot(1, 2, 2, projection="3d") if three_d else None
    for label, P in trajectories.items():
        P = np.asarray(P, dtype=float).reshape(-1, 3)
        kw = style(label, roles)
        top.plot(P[:, 0], P[:, 1], label=label, **kw)
        if ax3 is not None:
            ax3.plot(P[:, 0], P[:, 1], P[:, 2], label=label, **kw)
    for label, P in (points or {}).items():
        P = np.asarray(P, dtype=float).reshape(-1, 3)
        kw = style(label, roles)
        top.scatter(P[:, 0], P[:, 1], label=label, **kw)
        if ax3 is not None:
            ax3.scatter(P[:, 0], P[:, 1], P[:, 2], label=label, **kw)
    for label, S in (segments or {}).items():
        from matplotlib.collections import LineCollection

        S = np.asarray(S, dtype=float).reshape(-1, 2, 3)
        kw = style(label, roles)
        top.add_collection(LineCollection(S[:, :, :2], label=f"{label} ({len(S)})", **kw))
        if ax3 is not None:
            from mpl_toolkits.mplot3d.art3d import Line3DCollection

            ax3.add_collection(Line3DCollection(S, label=f"{label} ({len(S)})", **kw))
    for label, C in (outlines or {}).items():
        from matplotlib.collections import LineCollection

        top.add_collection(LineCollection(np.asarray(C, dtype=float), label=label, **style(label, roles)))
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.set_title("top view")
    top.set_aspect("equal", adjustable="datalim")
    top.legend(loc="best")
    if ax3 is not None:
        ax3.set_xlabel("x [m]")
        ax3.set_ylabel("y [m]")
        ax3.set_zlabel("z [m]")
        ax3.set_title("3-D")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def positions(values: gtsam.Values, is3d: bool, group: str | None = None) -> np.ndarray:
    """Translations of the poses in ``values`` in key order, shape (N, 3) (z = 0 in 2-D).

    Similarity3 (``group``): the image of the origin, s·t (GTSAM's action p ↦ s(Rp + t)).
    """
    keys = pose_keys(values)
    if group == "Similarity3":
        origin = np.zeros(3)
        return np.array([values.atSimilarity3(k).transformFrom(origin) for k in keys]).reshape(-1, 3)
    if is3d:
        return np.array([values.atPose3(k).translation() for k in keys]).reshape(-1, 3)
    out = np.zeros((len(keys), 3))
    for n, k in enumerate(keys):
        p = values.atPose2(k)
        out[n, :2] = (p.x(), p.y())
    return out


def edge_segments(positions: np.ndarray, graph, edges) -> np.ndarray:
    """(K, 2, 3) the end positions of ``graph``'s edges ``edges`` (indices), from ``positions``
    (P, 3) in ``graph.keys`` order (:func:`positions` of values holding every pose)."""
    ends = graph.index(np.asarray(graph.edge_keys)[np.asarray(edges, dtype=np.int64)].reshape(-1))
    return np.asarray(positions, dtype=float)[ends].reshape(-1, 2, 3)


def landmark_positions(values: gtsam.Values, is3d: bool) -> np.ndarray:
    """Landmark points of ``values`` in key order, shape (M, 3) (z = 0 in 2-D)."""
    keys = landmark_keys(values)
    out = np.zeros((len(keys), 3))
    for n, k in enumerate(keys):
        if is3d:
            out[n] = values.atPoint3(k)
        else:
            out[n, :2] = values.atPoint2(k)
    return out


#: χ²(2) at 0.95: the squared Mahalanobis radius of a 2-D Gaussian's 95 % ellipse.
CHI2_2DOF_95 = 5.991464547107979

#: At most this many poses get an ellipse (evenly spaced along the keys).
MAX_ELLIPSES = 120


def covariance_ellipses(poses: np.ndarray, covariances: np.ndarray, points: int = 48) -> np.ndarray:
    """(K, points, 2): the 95 % position ellipse of each 2-D pose (K ≤ :data:`MAX_ELLIPSES`).

    ``poses`` (n, 3, 3) Pose2 or Similarity2 matrices [[A, t], [0, 1]]; ``covariances`` (n, d, d)
    in their tangent order, x and y first: to first order a perturbation δ moves the position by
    A·δ_xy, so its covariance in the map's frame is A·Σ_xy·Aᵀ."""
    pick = np.unique(np.linspace(0, len(poses) - 1, min(len(poses), MAX_ELLIPSES)).round().astype(np.int64))
    A = poses[pick, :2, :2]
    S = A @ covariances[pick, :2, :2] @ np.swapaxes(A, 1, 2)
    w, V = np.linalg.eigh(S)
    angle = np.linspace(0.0, 2.0 * np.pi, points)
    circle = np.stack([np.cos(angle), np.sin(angle)])  # (2, points)
    radii = np.sqrt(CHI2_2DOF_95 * np.clip(w, 0.0, None))  # (K, 2)
    shape = V @ (radii[:, :, None] * circle[None])  # (K, 2, points)
    return np.swapaxes(shape, 1, 2) + poses[pick, None, :2, 2]


def plot_result(path: str, pg, result, title: str, incremental: bool = False, ellipses: bool = False) -> None:
    """The command's plot of a run on ``pg``: the start and the estimate (top view, and 3-D for a
    3-D graph), the landmarks of each, the loop closures rejected under ``--robust``/``--gnc``
    drawn between their optimized poses, and with ``ellipses`` (2-D) the estimate's 95 %
    position ellipses (:func:`covariance_ellipses`)."""
    if incremental:
        start, estimate, start_points, points = ("initial (online guesses)", "ISAM2 estimate", "initial landmarks",
                                                 "estimated landmarks")
    else:
        start, estimate, start_points, points = (f"initial ({result.init})", "optimized", "initial landmarks",
                                                 "optimized landmarks")
    roles = {start: "initial", estimate: "optimized", start_points: "initial landmarks", points: "optimized landmarks"}
    values, begin = result.values, result.start
    trajectories = {start: positions(begin, pg.is3d, pg.group), estimate: positions(values, pg.is3d, pg.group)}
    landmarks = ({start_points: landmark_positions(begin, pg.is3d), points: landmark_positions(values, pg.is3d)}
                 if pg.landmark_count else None)
    rejected = result.outliers
    segments = ({"rejected loop closures": edge_segments(trajectories[estimate], pg, rejected)}
                if rejected is not None and len(rejected) else None)
    outlines = ({"95% position ellipses": covariance_ellipses(result.poses, result.covariances())}
                if ellipses else None)
    plot_trajectories(path, trajectories, title, three_d=pg.is3d, points=landmarks, segments=segments,
                      outlines=outlines, roles=roles)


def plot_evaluation(path: str, evaluation) -> None:
    """The aligned estimate over the reference, as evo draws it: the reference dashed grey, the
    estimate coloured by its position error (top view; a colour bar in metres)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.5, 6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ref = evaluation.reference.positions
    est = evaluation.aligned.positions
    ax.plot(ref[:, 0], ref[:, 1], color="grey", ls="--", lw=1.0, label="reference")
    e = evaluation.errors
    segments = np.stack([est[:-1, :2], est[1:, :2]], axis=1)
    lines = LineCollection(segments, cmap="jet", lw=1.5)
    lines.set_array(0.5 * (e[:-1] + e[1:]))
    lines.set_clim(float(e.min()), float(e.max()))
    ax.add_collection(lines)
    fig.colorbar(lines, ax=ax, label="ATE (m)")
    ax.autoscale()
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"ATE RMSE {evaluation.ate.rmse:.4g} m ({evaluation.alignment}-aligned, {evaluation.ate.count} poses)")
    ax.legend(loc="best")
    fig.savefig(path, format="png", dpi=110)
