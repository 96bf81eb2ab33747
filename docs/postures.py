"""Draw answer postures as capsules, front and side views: docs/figures/postures.png.

Usage: python docs/postures.py ATLAS [-o docs/figures/postures.png] [--goals "X,Y,Z;X,Y,Z"] [--strategy NAME]

Asks the atlas's selector (refinement on, a generous budget) for a dozen
goals of the right hand around the body, and draws each answer's posture
with the body's collision capsules: front view (y, z) above, side view
(x, z) below (``--top``: and from above), the goal as a red cross, the
strategy's name in the title; a seated body's seat in light grey.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

from oracles.bodies.body import load_body  # noqa: E402
from oracles.protocol import OracleSpec  # noqa: E402
from reach.answers.select import Selector  # noqa: E402
from reach.maps.atlas import Atlas, load_atlas

GOALS = [
    (0.45, -0.25, 1.25), (0.35, -0.30, 0.95), (0.40, -0.20, 0.75), (0.30, -0.45, 1.45),
    (0.20, -0.60, 1.10), (0.55, -0.10, 1.50), (0.10, -0.30, 1.90), (0.60, -0.20, 1.00),
    (0.40, 0.10, 1.10), (0.45, -0.20, 0.40), (0.35, -0.15, 0.10), (0.35, -0.15, 0.05),
]


def draw(ax, body, q: np.ndarray, axes: tuple[int, int]) -> None:  # noqa: ANN001
    data = body.model.createData()
    pin.forwardKinematics(body.model, data, q)
    model = body.collision
    # Points per metre of the plot, for capsule widths drawn to scale.
    scale = 72 * ax.figure.get_size_inches()[1] / 4 / 2.2
    depth = ({0, 1, 2} - set(axes)).pop()  # the axis the view looks along: the nearest capsules drawn last
    order = sorted(range(len(model.placed)), key=lambda i: model.world(data, i)[0][depth])
    for i in order:
        a, b = model.world(data, i)
        name = model.placed[i].name
        colour = "#c44e52" if name.startswith("right_") else "#4c72b0" if name.startswith("left_") else "#8c8c8c"
        ax.plot([a[axes[0]], b[axes[0]]], [a[axes[1]], b[axes[1]]], color=colour, lw=2 * model.placed[i].radius * scale,
                solid_capstyle="round", alpha=0.85)


VIEWS = (((1, 2), "front view (y, z) [m]"), ((0, 2), "side view (x, z) [m]"))


def draw_furniture(ax, body, axes: tuple[int, int]) -> None:  # noqa: ANN001
    """A seated body's seat (pan, backrest) as light outlines, drawn under the body."""
    from scipy.spatial import ConvexHull

    for box in body.furniture:
        pts = box.corners()[:, list(axes)]
        hull = pts[ConvexHull(pts).vertices]
        ax.fill(hull[:, 0], hull[:, 1], color="#d9d9d9", ec="#999", lw=0.6, zorder=0)


def only(atlas: Atlas, name: str) -> Atlas:
    """The atlas with one strategy's tree alone (a strategy later in the priority order answers only what the ones
    before it do not reach)."""
    return Atlas(atlas.path, {**atlas.manifest, "strategies": [s for s in atlas.manifest["strategies"]
                                                               if s["name"] == name]},
                 {name: atlas.trees[name]}, {k: v for k, v in atlas.indexes.items() if k == name})


def _goals(text: str) -> list[tuple[float, ...]]:
    try:
        goals = [tuple(float(v) for v in part.split(",")) for part in text.split(";") if part.strip()]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z;X,Y,Z... in metres, got {text!r}") from exc
    if not goals or any(len(g) != 3 for g in goals):
        raise argparse.ArgumentTypeError(f"expected X,Y,Z;X,Y,Z... in metres, got {text!r}")
    return goals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas")
    parser.add_argument("-o", "--output", default="docs/figures/postures.png")
    parser.add_argument("--goals", type=_goals, default=GOALS, metavar="X,Y,Z;X,Y,Z...",
                        help="goals [m] of the right hand, world frame, ';'-separated (default: the README's twelve); "
                             "write --goals=... when the first value is negative")
    parser.add_argument("--strategy", help="ask this strategy's tree alone (a strategy later in the priority order "
                                           "answers only what the ones before it do not reach)")
    parser.add_argument("--top", action="store_true", help="add a view from above (x forward, y left)")
    parser.add_argument("--chain", action="store_true",
                        help="ask each goal with the previous answer as the current posture (`from`), as an "
                             "animation does")
    args = parser.parse_args()
    goals = args.goals
    atlas = load_atlas(args.atlas)
    if args.strategy:
        if args.strategy not in atlas.trees:
            parser.error(f"--strategy: no strategy {args.strategy!r} in {args.atlas}; "
                         f"there are {', '.join(atlas.trees)}")
        atlas = only(atlas, args.strategy)
    body = load_body(OracleSpec.from_dict(next(iter(atlas.trees.values())).meta["oracle"]).params["body"])
    selector = Selector(atlas, budget=0.5).warm_up()
    views = VIEWS if not args.top else (*VIEWS, ((0, 1), "top view (x, y) [m]"))
    fig, axs = plt.subplots(len(views), len(goals), figsize=(2.0 * len(goals), 4.25 * len(views)), squeeze=False)
    wide = max(0.7, max(abs(g[1]) for g in goals) + 0.15)  # [m] the front view's half width: every goal in it
    start: dict[str, float] | None = None
    for k, goal in enumerate(goals):
        a = selector.select("right_hand", np.array(goal), start=start)
        if args.chain and a.reachable and a.posture:
            start = a.as_start()
        for row, (axes, _) in enumerate(views):
            ax = axs[row, k]
            if axes[1] == 2:
                ax.axhline(0.0, color="#444", lw=0.8)
            draw_furniture(ax, body, axes)
            if a.reachable and a.posture:
                draw(ax, body, body.configuration(a.posture, a.root), axes)
            ax.plot(goal[axes[0]], goal[axes[1]], "x", color="red", ms=9, mew=2.5)
            ax.set_xlim(-wide, wide) if axes[0] == 1 else ax.set_xlim(-0.5, 0.9)
            ax.set_ylim(-0.05, 2.15) if axes[1] == 2 else ax.set_ylim(-wide, wide)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([] if k else ([0, 0.5, 1.0, 1.5, 2.0] if axes[1] == 2 else [-0.5, 0, 0.5]))
            if axes[0] == 1:
                ax.invert_xaxis()  # the front view: the body's right on the left of the picture, as facing it
        title = f"{a.strategy or 'unreachable'}\n{a.refined}" if a.reachable else "unreachable"
        axs[0, k].set_title(f"({goal[0]:.2f}, {goal[1]:.2f}, {goal[2]:.2f})\n{title}", fontsize=8)
    for row, (_, label) in enumerate(views):
        axs[row, 0].set_ylabel(label)
    fig.tight_layout()
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=80)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
