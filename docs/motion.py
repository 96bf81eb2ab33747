"""Draw reach motions as strips of frames with the hand's speed: docs/figures/motion_arm.png, motion_crouch.png.

Usage: python docs/motion.py ATLAS [--out docs/figures] [--motion NAME X,Y,Z] [--strategy NAME] [--return]

Plans the right hand's motion from the reference posture to an arm goal and
to a crouch goal (the README's; ``--motion``: others instead, ``--strategy``:
asked of that strategy's tree alone, ``--return``: there and back), then
draws, for each: the body's capsules
at five key times, side by side (side view, x forward and z up), the hand's
path so far in red and the goal as a cross; below, the hand's speed against
time beside the minimum-jerk profile the timing follows for the same path
length.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from postures import draw, only  # noqa: E402

from oracles.bodies.body import load_body  # noqa: E402
from oracles.protocol import OracleSpec  # noqa: E402
from reach.answers.select import Selector  # noqa: E402
from reach.maps.atlas import load_atlas
from reach.motion.planner import Planner  # noqa: E402

MOTIONS = {"arm": (0.45, -0.25, 1.20), "crouch": (0.35, -0.15, 0.05)}
KEYS = 5  # frames drawn per strip


def figure(planner: Planner, body, name: str, goal: tuple[float, ...], out: Path,  # noqa: ANN001
           back: bool = False) -> Path:
    m = planner.plan("right_hand", goal, back=back)
    fig = plt.figure(figsize=(2.0 * KEYS, 6.6))
    grid = fig.add_gridspec(2, KEYS, height_ratios=[3.0, 1.3])
    picks = np.round(np.linspace(0, len(m.times) - 1, KEYS)).astype(int)
    for j, k in enumerate(picks):
        ax = fig.add_subplot(grid[0, j])
        ax.axhline(0.0, color="#444", lw=0.8)
        draw(ax, body, m.postures[k], (0, 2))
        ax.plot(m.path[: k + 1, 0], m.path[: k + 1, 2], "-", color="red", lw=1.5)
        ax.plot(goal[0], goal[2], "x", color="black", ms=8, mew=2)
        ax.set_xlim(-0.5, 0.9)
        ax.set_ylim(-0.05, 2.05)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([] if j else [0, 0.5, 1.0, 1.5, 2.0])
        ax.set_title(f"t = {m.times[k]:.2f} s", fontsize=9)
    fig.axes[0].set_ylabel("side view (x, z) [m]")
    speed = np.linalg.norm(np.diff(m.path, axis=0), axis=1) * m.rate
    mid = 0.5 * (m.times[1:] + m.times[:-1])
    leg = m.duration / (2 if back else 1)  # there and back: two minimum-jerk legs
    u = (mid % leg) / leg
    length = float(np.linalg.norm(np.diff(m.path, axis=0), axis=1).sum())
    ax = fig.add_subplot(grid[1, :])
    ax.plot(mid, speed, "o-", ms=3, color="#c44e52", label="hand speed (frames)")
    ax.plot(mid, length / m.duration * 30 * u**2 * (1 - u) ** 2, "--", color="#444", label="minimum jerk, same path "
        "length")  # (the path twice as long over twice the time: the same peak when there and back)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("speed [m/s]")
    ax.set_xlim(0, m.duration)
    ax.legend(fontsize=8, loc="upper right")
    parts = ", ".join(f"{k} {v:.1f} TMU" for k, v in m.parts.items())
    fig.suptitle(f"right hand to ({goal[0]:.2f}, {goal[1]:.2f}, {goal[2]:.2f}) m: {m.strategy}, {m.duration:.2f} s "
                 f"({parts}),\n{len(m.times)} frames at {m.rate:g} Hz, {m.waypoints} stored postures on the way, "
                 f"{m.held} frames held", fontsize=9)
    fig.tight_layout()
    path = out / f"motion_{name}.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas")
    parser.add_argument("--out", default="docs/figures", help="folder of the figures (default docs/figures)")
    parser.add_argument("--motion", nargs=2, action="append", metavar=("NAME", "X,Y,Z"),
                        help="a motion to draw, to motion_NAME.png (repeatable; default the README's two)")
    parser.add_argument("--strategy", help="ask this strategy's tree alone")
    parser.add_argument("--return", dest="back", action="store_true", help="there and back")
    args = parser.parse_args()
    atlas = load_atlas(args.atlas)
    if args.strategy:
        atlas = only(atlas, args.strategy)
    motions = ({n: tuple(float(v) for v in g.split(",")) for n, g in args.motion} if args.motion else MOTIONS)
    body = load_body(OracleSpec.from_dict(next(iter(atlas.trees.values())).meta["oracle"]).params["body"])
    planner = Planner(Selector(atlas).warm_up(), budget=2.0)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, goal in motions.items():
        print(f"wrote {figure(planner, body, name, goal, out, args.back)}")


if __name__ == "__main__":
    main()
