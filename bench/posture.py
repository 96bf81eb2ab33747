"""How human are the answers? The figures of the issue "Human answers", measured on an atlas.

Usage: python bench/posture.py ATLAS [--goals 200] [--pairs 300] [--handover-deg 5]

Prints JSON lines:

* ``inside_body``: per strategy, the share of its inner volume inside the
  capsules of the body that the strategy does not move, at the reference
  posture (points drawn uniformly in the inner cells);
* ``stored_collisions``: per strategy, the share of stored reachable
  postures (up to 500) that coal finds in collision (any pair of the
  self-collision task closer than it accepts);
* ``elbow``: of the right_arm answers for goals in front (x >= 0.25 m) and
  below the right shoulder, the share with the elbow above the shoulder;
* ``near_limits``: the share of right-hand answers with an arm joint within
  5 deg of a limit;
* ``near_limits_spine_low``: of answers to goals low in front (z 0.1-0.7 m,
  where the trunk strategies answer), the share with a lumbar, thoracic or
  neck joint within 5 deg of a limit;
* ``neighbours``: over pairs of goals 1 cm apart answered by the same
  strategy, the 99th percentile and maximum of the largest joint change
  [deg], asked independently and asked with the first answer as ``from``,
  in front of the chest and low in front (where the trunk strategies answer);
  and how many pairs the selector answered with two strategies (a jump too);
* ``sagittal``: of 18 goals straight ahead of the right shoulder (x 0.3-0.6 m, z 0.1-1.4 m), the answers with a
  joint other than the right arm's and clavicle's moved to within 1 deg of a limit, and the pelvis's largest shift aside
  [m] (a person keeps them off their limits and the pelvis over the feet);
* ``turning``: of goals beside and behind the body at the right shoulder's height (0.6-0.9 m from it, 60-270 deg
  round from straight ahead towards the left, i.e. across the body and behind it), per answering strategy, the
  share with the lumbar side-bend or the thoracic twist within 1 deg of a limit, and the pelvis's median turn [deg]
  (a person turns to reach behind, rather than bending the spine to its limits);
* ``idle_arm`` (a seated atlas: its body's furniture has a ``seat_pan``; the measures above are for a
  standing atlas and are skipped): of the answers to goals in front of the seat (x 0.2-0.9 m, y -0.6-0.3 m,
  z 0.4-1.3 m in the seat's frame), per strategy, the share whose idle (left) arm's elbow, wrist or fingertip
  lies outside the seat's side, and the farthest [m] (the idle arm stays within the seat's sides);
* ``lowest``: the lowest reachable grip-centre height [m] of the whole body
  and of crouch in front of the feet: the lowest reachable vertex
  (0.1 <= x <= 0.5 m, |y| <= 0.3 m), and, independent of the resolution, the
  height found by bisection with the strategy's referee at three points.

The selector hands goals over as a server does (``--handover-deg``, default
5; 0 for the paper's plain priority). Goals are drawn with fixed seeds, one stream per measure, so figures are
repeatable and every atlas is measured on the same goals.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
from pathlib import Path

import numpy as np

from oracles.bodies.body import load_body
from oracles.ik.problem import ReachProblem
from oracles.ik.strategy import parse_strategy
from oracles.protocol import OracleSpec
from oracles.tasks.base import moved
from reach.answers.select import HANDOVER, Selector
from reach.maps.atlas import load_atlas
from reach.maps.tree import INNER

SPINE = ("lumbar_", "thoracic_", "neck_")  # the trunk and neck joints of the generated human
ARM_JOINTS = ("shoulder", "elbow", "forearm", "wrist")
FRONT_BOX = ([0.1, -0.6, 0.7], [0.6, 0.0, 1.7])  # [m] goals in front of the chest (the arm and the upper body answer)
LOW_BOX = ([0.2, -0.5, 0.1], [0.7, 0.1, 0.7])  # [m] goals low in front (the trunk strategies answer)
NEAR_LIMIT = np.radians(5.0)  # [rad] a joint this close to a limit counts as at it
SAGITTAL_LIMIT = np.radians(1.0)  # [rad] ... and this close, as on it (the sagittal goals' measure)
SEATED_BOX = ([0.2, -0.6, 0.4], [0.9, 0.3, 1.3])  # [m] goals in front of a seated body, in the seat's frame
IDLE_POINTS = ("left_elbow_flexion", "left_wrist_flexion", "left_fingertip")  # the idle arm's points measured
LOW_POINTS = ((0.25, -0.15), (0.35, -0.2), (0.5, -0.2), (0.6, -0.2), (0.7, -0.2))  # [m] in front of the feet


def emit(**fields: object) -> None:
    print(json.dumps(fields), flush=True)


def inside_capsules(body, q, capsules: list[int], points: np.ndarray) -> np.ndarray:  # noqa: ANN001
    import pinocchio as pin

    model = body.collision
    data = body.model.createData()
    pin.forwardKinematics(body.model, data, q)
    inside = np.zeros(len(points), bool)
    for i in capsules:
        a, b = model.world(data, i)
        d = b - a
        t = np.clip(((points - a) @ d) / max(d @ d, 1e-12), 0.0, 1.0)
        inside |= np.linalg.norm(points - (a + t[:, None] * d), axis=1) <= model.placed[i].radius
    return inside


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas")
    parser.add_argument("--goals", type=int, default=200)
    # 300, not the 100: of 100 pairs the 99th percentile is the
    # second-largest change, decided by which one or two pairs straddle a
    # boundary between two postures' basins (low in front, same atlas: 3.8 deg
    # on 94 pairs, 19.0 deg on 293).
    parser.add_argument("--pairs", type=int, default=300, help="pairs of goals 1 cm apart per region (default 300)")
    parser.add_argument("--budget", type=float, default=0.5, help="refinement budget [s] (generous: figures, not "
        "latency)")
    parser.add_argument("--handover-deg", type=float, default=math.degrees(HANDOVER), help="the selector's handover "
        "margin [deg]")
    args = parser.parse_args()
    atlas = load_atlas(args.atlas)
    emit(bench="machine", python=platform.python_version(), processor=platform.processor() or platform.machine(),
         atlas=str(Path(args.atlas)), handover_deg=args.handover_deg)
    rng = np.random.default_rng(0)
    specs = {name: OracleSpec.from_dict(tree.meta["oracle"]) for name, tree in atlas.trees.items()}
    body = load_body(next(iter(specs.values())).params["body"])
    for name, tree in atlas.trees.items():
        p = specs[name].params
        strategy = parse_strategy(body, p["effector"], p["joints"], [{"type": "reach"}, {"type": "self_collision"}])
        ReachProblem(body, strategy)
        active = frozenset(strategy.joints)
        static = [i for i, c in enumerate(body.collision.placed) if not moved(body.model, c.joint, active)]
        sel = np.nonzero(tree.kind == INNER)[0]
        vol = tree.lattice.cell_size(tree.depth[sel]).prod(axis=1)
        pick = sel[rng.choice(sel.size, size=20000, p=vol / vol.sum())]
        pts = tree.lattice.points(tree.corner[pick]) + rng.random((20000, 3)) * tree.lattice.cell_size(tree.depth[pick])
        share = float(inside_capsules(body, body.q_ref, static, pts).mean()) if static else None
        task = strategy.task("self_collision")
        ok = np.nonzero(tree.vertices.reachable)[0]
        rows = rng.choice(ok, size=min(500, ok.size), replace=False)
        floors = np.array([pr.floor for pr in task.pairs])
        colliding = ([bool(np.any(task.distances(q) < floors)) for q in tree.vertices.posture[rows]] if task.pairs
                     else [False])
        emit(bench="inside_body", strategy=name, static_capsules=len(static), share=share)
        emit(bench="stored_collisions", strategy=name, postures=int(rows.size), share=float(np.mean(colliding)))

    selector = Selector(atlas, budget=args.budget, handover=math.radians(args.handover_deg)).warm_up()
    pans = [box for box in body.furniture if box.name == "seat_pan"]
    if pans:
        idle_arm(body, selector, atlas, pans[0], args.goals)
        return
    tree_names = list(atlas.trees["right_arm"].vertices.posture_names)
    shoulder_z = body.frame_positions(names=["right_shoulder"])["right_shoulder"][2]
    # Each measure draws from its own stream: the goals do not depend on how
    # many draws the atlas's trees took above, so atlases compare on the same goals.
    goals = np.random.default_rng(1).uniform([0.1, -0.6, 0.6], [0.7, 0.1, 1.8], (args.goals, 3))
    answers = selector.select_many("right_hand", goals)
    elbow_high, front_low, near = 0, 0, 0
    arm_idx = [k for k, n in enumerate(tree_names) if n.startswith("right_") and any(j in n for j in ARM_JOINTS)]
    lower, upper = body.model.lowerPositionLimit, body.model.upperPositionLimit

    def near_limit(q: np.ndarray, idx: list[int]) -> bool:
        return any(q[k] - lower[k] < NEAR_LIMIT or upper[k] - q[k] < NEAR_LIMIT for k in idx)

    answered = 0
    for g, a in zip(goals, answers, strict=True):
        if not a.reachable or a.posture is None:
            continue
        answered += 1
        q = body.configuration(a.posture, a.root)
        if near_limit(q, arm_idx):
            near += 1
        if a.strategy == "right_arm" and g[0] >= 0.25 and g[2] < shoulder_z:
            front_low += 1
            frames = body.frame_positions(q, ["right_shoulder"])
            elbow = elbow_position(body, q)
            elbow_high += int(elbow[2] > frames["right_shoulder"][2])
    emit(bench="elbow", goals_in_front_below_shoulder=front_low, elbow_above_shoulder=elbow_high,
         share=elbow_high / max(front_low, 1))
    emit(bench="near_limits", answers=answered, within_5deg=near, share=near / max(answered, 1))
    # Low in front the trunk strategies answer, and at the edges of their
    # volumes the spine bends and twists to its limits (README, "Found and left").
    low = np.random.default_rng(4).uniform(*LOW_BOX, (args.goals, 3))
    spine_idx = [k for k, n in enumerate(tree_names) if n.startswith(SPINE)]
    spine, low_answered = 0, 0
    for a in selector.select_many("right_hand", low):
        if a.reachable and a.posture is not None:
            low_answered += 1
            q = body.configuration(a.posture, a.root)
            spine += int(near_limit(q, spine_idx))
    emit(bench="near_limits_spine_low", answers=low_answered, within_5deg=spine, share=spine / max(low_answered, 1))

    # Goals in front of the chest (mostly the arm and the upper body), and low
    # in front (the upper body, the whole body and the crouch).
    for region, seed, box in (("front", 2, FRONT_BOX), ("low", 3, LOW_BOX)):
        pairs = np.random.default_rng(seed)
        base = pairs.uniform(*box, (args.pairs, 3))
        step = pairs.normal(size=base.shape)
        step *= 0.01 / np.linalg.norm(step, axis=1, keepdims=True)
        for mode in ("independent", "from"):
            changes, used, switches = [], set(), 0
            for g, s in zip(base, step, strict=True):
                a = selector.select("right_hand", g)
                b = selector.select("right_hand", g + s, start=a.as_start() if mode == "from" else None)
                if a.reachable and b.reachable and a.strategy == b.strategy and a.posture and b.posture:
                    changes.append(max(abs(a.posture[k] - b.posture[k]) for k in a.posture))
                    used.add(a.strategy)
                # a change of strategy: a jump of its own
                switches += int(a.reachable and b.reachable and a.strategy != b.strategy)
            c = np.degrees(changes) if changes else np.zeros(1)
            emit(bench="neighbours", region=region, mode=mode, pairs=len(changes), strategies=sorted(used),
                 p99_deg=round(float(np.percentile(c, 99)), 2), max_deg=round(float(c.max()), 2),
                 over_10deg=int(np.sum(c > 10)), median_deg=round(float(np.median(c)), 3), strategy_switches=switches)

    for name in ("right_whole_body", "right_crouch"):
        if name not in atlas.trees:
            continue
        tree = atlas.trees[name]
        v = tree.vertices
        pts = tree.lattice.points(tree.lattice.coords(v.keys))
        front = v.reachable & (pts[:, 0] >= 0.1) & (pts[:, 0] <= 0.5) & (np.abs(pts[:, 1]) <= 0.3)
        # Independent of the tree's resolution: bisect the height at points in
        # front of the feet with the strategy's thorough referee.
        referee = OracleSpec.from_dict(tree.meta["oracle"]).create().variant("referee",
            restarts=6)  # type: ignore[attr-defined]
        lowest = []
        for x, y in LOW_POINTS:
            lo, hi = 0.0, 0.6
            if referee.evaluate(np.array([[x, y, lo]])).reachable[0]:
                lowest.append(0.0)
                continue
            while hi - lo > 0.005:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if referee.evaluate(np.array([[x, y, mid]])).reachable[0] else (mid, hi)
            lowest.append(round(hi, 3))
        emit(bench="lowest", strategy=name, lowest_vertex_z=float(pts[front, 2].min()) if front.any() else None,
             resolution=tree.lattice.resolution.tolist(), lowest_by_ik_z=lowest, at_xy=[list(p) for p in LOW_POINTS])

    # Goals straight ahead of the right shoulder (its sagittal plane), low to high: a person reaches them without
    # other joints at their limits and with the pelvis over the feet (the measures of docs/validation.md).
    shoulder = body.frame_positions(names=["right_shoulder"])["right_shoulder"]
    sagittal = np.array([[x, shoulder[1], z] for x in (0.3, 0.45, 0.6) for z in (0.1, 0.3, 0.5, 0.8, 1.1, 1.4)])
    own = set(arm_idx) | {k for k, n in enumerate(tree_names) if n.startswith("right_clavicle")}
    others = [k for k, n in enumerate(tree_names) if k not in own and not n.startswith("root_")]
    at_limit, shifts, examples, reached = 0, [], [], 0
    for g, a in zip(sagittal, selector.select_many("right_hand", sagittal), strict=True):
        if not a.reachable or a.posture is None:
            continue
        reached += 1
        q = body.configuration(a.posture, a.root)
        # at a limit it was moved to (straight knees and a straight idle elbow at the reference are not counted)
        hit = [tree_names[k] for k in others if (q[k] - lower[k] < SAGITTAL_LIMIT or upper[k] - q[k] < SAGITTAL_LIMIT)
               and abs(q[k] - body.q_ref[k]) > SAGITTAL_LIMIT]
        shifts.append(abs(float(q[1] - body.q_ref[1])))
        if hit:
            at_limit += 1
            examples.append({"goal": g.round(3).tolist(), "strategy": a.strategy, "joints": hit})
    turning(body, selector, shoulder, args.goals)
    emit(bench="sagittal", goals=len(sagittal), reached=reached, other_joint_at_limit=at_limit,
         pelvis_shift_max_m=round(max(shifts, default=0.0), 3),
         pelvis_shift_over_5cm=int(sum(shift > 0.05 for shift in shifts)), examples=examples[:6])


def turning(body, selector: Selector, shoulder: np.ndarray, n: int) -> None:  # noqa: ANN001
    """The ``turning`` measure: how each strategy answers goals across and behind the body at shoulder height."""
    import pinocchio as pin

    rng = np.random.default_rng(6)
    az, r = np.radians(rng.uniform(60.0, 270.0, n)), rng.uniform(0.6, 0.9, n)
    goals = shoulder + np.column_stack([r * np.cos(az), r * np.sin(az), np.zeros(n)])
    names = list(body.q_names)
    spine = [names.index(j) for j in ("lumbar_lateral", "thoracic_rotation")]
    lower, upper = body.model.lowerPositionLimit, body.model.upperPositionLimit
    rows: dict[str, list[tuple[bool, float]]] = {}
    for a in selector.select_many("right_hand", goals):
        if a.reachable and a.posture is not None:
            q = body.configuration(a.posture, a.root)
            limit = any(q[k] - lower[k] < SAGITTAL_LIMIT or upper[k] - q[k] < SAGITTAL_LIMIT for k in spine)
            r_ = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
            rows.setdefault(a.strategy, []).append((limit, math.degrees(math.atan2(r_[1, 0], r_[0, 0]))))
    for name, got in sorted(rows.items()):
        emit(bench="turning", strategy=name, answers=len(got), spine_at_limit=int(sum(g[0] for g in got)),
             share_spine_at_limit=round(float(np.mean([g[0] for g in got])), 3),
             pelvis_turn_median_deg=round(float(np.median([abs(g[1]) for g in got])), 1))


def idle_arm(body, selector: Selector, atlas, pan, n: int) -> None:  # noqa: ANN001
    """The ``idle_arm`` measure of a seated atlas: how far the left arm's points go past the pan's left side."""
    side = pan.hi[1]  # [m] the seat's left side (the pan is axis-aligned in the seat's frame)
    goals = np.random.default_rng(5).uniform(*SEATED_BOX, (n, 3))
    effector = next(iter({tree.meta["oracle"]["params"]["effector"] for tree in atlas.trees.values()}))
    rows: dict[str, list[float]] = {}
    for a in selector.select_many(effector, goals):
        if a.reachable and a.posture is not None:
            q = body.configuration(a.posture, a.root)
            idle = body.frame_positions(q, list(IDLE_POINTS))
            rows.setdefault(a.strategy, []).append(max(p[1] for p in idle.values()))
    for name, ys in sorted(rows.items()):
        out = np.array(ys) - side
        emit(bench="idle_arm", strategy=name, answers=len(ys), seat_side_y=round(float(side), 3),
             outside=int(np.sum(out > 0)), share_outside=round(float(np.mean(out > 0)), 3),
             farthest_outside_m=round(float(max(out.max(), 0.0)), 3), idle_arm_max_y=round(float(max(ys)), 3))


def elbow_position(body, q: np.ndarray) -> np.ndarray:  # noqa: ANN001
    import pinocchio as pin

    data = body.model.createData()
    pin.forwardKinematics(body.model, data, q)
    return np.asarray(data.oMi[body.joint_id("right_elbow_flexion")].translation)


if __name__ == "__main__":
    main()
