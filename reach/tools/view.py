"""``reach view``: an atlas and its answers in the browser, on viser.

viser serves a three.js page from the Python process (its client ships in
the wheel: the page works offline). The scene, in the atlas's world frame
(z up, x forward, metres):

* each strategy's volume, one layer per strategy in priority order, coloured
  by strategy: inner cells, boundary (final) cells or both, drawn as boxes
  (the paper's Figure 10), dots or wireframe (Figure 11), one instanced
  mesh per layer; optionally only the cells a higher-priority strategy does
  not already hold (Figure 8's "first strategy by priority"), and only those
  a slice plane cuts;
* the body, drawn from its collision capsules, in the reference posture and
  then in each answer's posture, and its furniture (a seated body's seat,
  the obstacles task's boxes) in grey;
* a goal to drag (a transform gizmo) or to type; every move asks the
  selector (or a running ``reach serve``, ``--connect``), and the panel shows
  the strategy, its colour, the alternatives, whether the posture was
  refined and its residual, the strategy that handed the goal over and the
  limits its posture came near, or that the goal is unreachable;
* the answer's reach motion (:mod:`reach.motion.planner`, or the server's
  ``motion`` operation with ``--connect``): planned on demand from the
  reference posture, played in real time (or slower), paused, or scrubbed frame by
  frame on the first atlas's body, with the hand's path drawn as a line.

Several atlases (a population study) stand side by side, ``spacing`` metres
apart along y, each with its own colours. :class:`Viewer` is also the
Python API the tests drive.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from reach.answers.answer import posture_vector
from reach.answers.select import Selector
from reach.errors import InputError, MotionError, ServerError, ServerUnavailable
from reach.maps.atlas import Atlas
from reach.maps.protocol import DEFAULT_POLICY, POLICIES
from reach.maps.tree import FINAL, INNER, VATree
from reach.motion.planner import Planner
from reach.serving.client import Client
from reach.tools import panel
from reach.tools.gate import Gate, guarded_websockets
from reach.tools.panel import SLICE_AXES
from reach.tools.playback import Playback

# Strategy colours (RGB), in priority order: matplotlib's tab10, the report's palette.
PALETTE = np.array([(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
                    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)], np.uint8)
UNREACHABLE = (200, 0, 0)
BOUNDARY_SHADE = 0.75  # boundary (final) cells are drawn this much darker than inner ones


def cube() -> tuple[np.ndarray, np.ndarray]:
    """A unit cube centred on the origin: vertices (8, 3) and triangles (12, 3)."""
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], np.float32)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.uint32)
    return v, f


def index_colours(index: np.ndarray) -> np.ndarray:
    """uint8 RGB (n, 3) of reachability indices in [0, 1] on matplotlib's viridis; NaN (no index there) grey."""
    # matplotlib (about half a second) only when a figure is drawn
    from matplotlib import colormaps

    rgb = (colormaps["viridis"](np.nan_to_num(index, nan=0.0))[:, :3] * 255).astype(np.uint8)
    rgb[~np.isfinite(index)] = 128
    return rgb  # type: ignore[no-any-return]


def quaternion_z_to(axis: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of the smallest rotation taking +z to a unit axis (a capsule mesh is built along z)."""
    rotation, _ = Rotation.align_vectors(np.asarray(axis, float)[None], [[0.0, 0.0, 1.0]])
    x, y, z, w = rotation.as_quat()
    return np.array([w, x, y, z])


@dataclass
class Cells:
    """The cells of one tree to draw: centres and edges [m], and which are inner."""

    centre: np.ndarray
    size: np.ndarray
    inner: np.ndarray

    @classmethod
    def of(cls, tree: VATree) -> Cells:
        rows = np.nonzero((tree.kind == INNER) | (tree.kind == FINAL))[0]
        size = tree.lattice.cell_size(tree.depth[rows])
        lo = tree.lattice.points(tree.corner[rows])
        return cls(lo + 0.5 * size, size, tree.kind[rows] == INNER)

    def select(self, mask: np.ndarray) -> Cells:
        return Cells(self.centre[mask], self.size[mask], self.inner[mask])


@dataclass
class Scene:
    """One atlas in the view: its selector (or server), trees, colours, body and offset."""

    atlas: Atlas
    offset: np.ndarray
    colours: np.ndarray  # (strategies, 3)
    cells: dict[str, Cells] = field(default_factory=dict)
    covered: dict[str, np.ndarray] = field(default_factory=dict)  # cells a higher-priority strategy holds
    shaper: Any = None
    capsules: list[Any] = field(default_factory=list)
    furniture: list[Any] = field(default_factory=list)  # box handles: the seat, the obstacles


class Viewer:
    """The viewer's state and its viser scene (see the module docstring).

    Args:
        atlases: One or more atlases (side by side).
        host, port: Where the page is served (127.0.0.1 by default: not on the network).
        connect: A running ``reach serve`` request address to take answers from
            (the atlases still give the volumes and the body).
        spacing: Distance [m] between atlases along y.
        policy: The selector's policy for boundary cells.
        refine: Refine answers by IK at the exact goal (the selector's default).
        accommodation: A population's accommodation volume: grid points (N, 3) [m] and the share (N,) of members whose
            trees hold each (:mod:`reach.tools.accommodation_report`), drawn as dots coloured by the share (viridis:
            dark 0, yellow 1) where it is at least the panel's threshold.
    """

    # The panel's controls and the scene's goal handles (viser's), made by reach.tools.panel.build.
    effector_box: Any
    goal_box: Any
    policy_box: Any
    answer_box: Any
    plan_button: Any
    play_button: Any
    frame_slider: Any
    speed_slider: Any
    motion_box: Any
    style_box: Any
    cells_box: Any
    first_box: Any
    index_box: Any
    slice_axis: Any
    slice_at: Any
    accommodation_box: Any
    accommodation_at: Any
    layer_boxes: dict[tuple[int, str], Any]
    gizmo: Any
    goal_markers: list[Any]

    def __init__(self, atlases: Sequence[Atlas], host: str = "127.0.0.1", port: int = 8080, connect: str | None = None,
                 spacing: float = 1.5, policy: str = DEFAULT_POLICY, refine: bool = True,
                 accommodation: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        import viser  # the optional dependency: pip install 'reach-volumes[view]'

        if not atlases:
            raise InputError("atlas", "at least one atlas is needed")
        if policy not in POLICIES:
            raise InputError("policy", f"expected one of {', '.join(POLICIES)}, got {policy!r}")
        # viser listens on a loopback port of its own; the gate, where the user asked, lets only this server's origin
        # through, and viser's port lets through only what the gate passed on (its Host is the gate's): the gate is
        # the only door (a rebound name reaches viser's port as well as the gate's).
        gate_names: set[str] = set()
        with guarded_websockets(lambda: gate_names) as guarded:
            self.server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        if not guarded:
            self.server.stop()
            raise InputError("viser", f"viser {viser.__version__} did not start its server through websockets' "
                                      "serve, so its own port "
                              "cannot be guarded; install a viser that does (1.1 does)")
        self.gate = Gate(host, port, self.server.get_port())
        gate_names.update(self.gate.hosts)
        self.host, self.port = host, self.gate.port
        self.refine, self.policy = refine, policy
        self.client = None
        if connect is not None:
            self.client = Client(connect)
        self._lock = threading.Lock()
        # layer -> (the settings it was drawn with, its handle)
        self._drawn: dict[tuple[int, str], tuple[tuple[Any, ...], Any]] = {}
        self.scenes: list[Scene] = []
        for k, atlas in enumerate(atlases):
            names = list(atlas.trees)
            # Atlas k takes every k-th colour family: a darker shade for the second atlas, and so on.
            colours = (PALETTE[np.arange(len(names)) % len(PALETTE)] * (1.0 - 0.35 * k)).astype(np.uint8)
            scene = Scene(atlas, np.array([0.0, spacing * k, 0.0]), colours)
            scene.cells = {n: Cells.of(t) for n, t in atlas.trees.items()}
            self.scenes.append(scene)
        self.selectors = [Selector(s.atlas, policy=policy, refine=refine) for s in self.scenes]  # type: ignore[arg-type]
        effectors = self.selectors[0].effectors
        self.effector = "right_hand" if "right_hand" in effectors else effectors[0]
        self.answers: list[dict[str, Any]] = []
        self.accommodation = accommodation
        # the dots' size: the grid's spacing (the smallest step between distinct coordinates on any axis)
        self._dot = 0.05 if accommodation is None else float(min(
            np.diff(np.unique(accommodation[0][:, i])).min(initial=0.05) for i in range(3)))
        self.goal = np.array([0.45, -0.25, 1.2])
        # the planned motion: its summary, times and postures (the shaper's order)
        self.motion: dict[str, Any] | None = None
        self._path: Any = None
        self._planner: Any = None
        self.playback = Playback()
        self.frame = 0  # the motion's frame shown
        panel.build(self)
        for k, scene in enumerate(self.scenes):
            panel.add_body(self, k, scene)
        self.draw()
        self.draw_accommodation()
        self.set_goal(self.goal)

    # -- the page -----------------------------------------------------------
    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def _pose(self, scene: Scene, caps: np.ndarray) -> None:
        for handle, cap in zip(scene.capsules, caps, strict=True):
            axis = cap[3:6] - cap[:3]
            n = float(np.linalg.norm(axis))
            handle.position = tuple(0.5 * (cap[:3] + cap[3:6]) + scene.offset)
            handle.wxyz = tuple(quaternion_z_to(axis / n) if n > 1e-9 else np.array([1.0, 0.0, 0.0, 0.0]))

    # -- volumes --------------------------------------------------------------
    def _covered(self, scene: Scene, name: str) -> np.ndarray:
        """Which of a strategy's cells a strategy of higher priority (same effector) already holds."""
        if name not in scene.covered:
            trees = scene.atlas.trees
            effector = trees[name].meta.get("effector")
            higher = [n for n in trees if n != name and trees[n].meta.get("effector") == effector
                      and (trees[n].meta.get("priority", 0), n) < (trees[name].meta.get("priority", 0), name)]
            centres = scene.cells[name].centre
            mask = np.zeros(len(centres), bool)
            for n in higher:
                mask |= scene.atlas.maps[n].contains(centres, self.policy)  # type: ignore[arg-type]
            scene.covered[name] = mask
        return scene.covered[name]

    def visible_cells(self, k: int, name: str) -> Cells:
        """The cells of a layer that the panel's settings show."""
        scene = self.scenes[k]
        cells = scene.cells[name]
        mask = np.ones(len(cells.centre), bool)
        if self.cells_box.value == "inner":
            mask &= cells.inner
        elif self.cells_box.value == "boundary":
            mask &= ~cells.inner
        if self.first_box.value:
            mask &= ~self._covered(scene, name)
        axis = SLICE_AXES.index(self.slice_axis.value) - 1
        if axis >= 0:
            at = float(self.slice_at.value)
            mask &= np.abs(cells.centre[:, axis] - at) <= 0.5 * cells.size[:, axis]
        return cells.select(mask)

    def draw(self) -> None:
        """Bring every layer in line with the panel: a layer drawn with today's settings is only shown or
        hidden (nothing is sent again); one drawn with others, or never, is sent anew."""
        with self._lock:
            settings = (self.style_box.value, self.cells_box.value, self.first_box.value, self.index_box.value,
                        self.slice_axis.value, self.slice_at.value, self.policy)
            for k, scene in enumerate(self.scenes):
                for i, name in enumerate(scene.atlas.trees):
                    visible = bool(self.layer_boxes[(k, name)].value)
                    drawn = self._drawn.get((k, name))
                    if drawn is not None and drawn[0] == settings:
                        if drawn[1] is not None:
                            drawn[1].visible = visible
                        continue
                    path = f"/atlas{k}/volumes/{name}"
                    self.server.scene.remove_by_name(path)
                    self._drawn.pop((k, name), None)
                    if visible:
                        self._drawn[(k, name)] = (settings, self._layer(k, i, name, path))

    def _layer(self, k: int, i: int, name: str, path: str) -> Any:
        """Send one layer to the page: one instanced mesh (or point cloud) of its visible cells; None when it has
        none."""
        scene = self.scenes[k]
        cells = self.visible_cells(k, name)
        if not len(cells.centre):
            return None
        centre = (cells.centre + scene.offset).astype(np.float32)
        if self.index_box.value and name in scene.atlas.indexes:
            colour = index_colours(scene.atlas.map(name).index_at(cells.centre, held=False))
        else:
            colour = np.tile(scene.colours[i], (len(centre), 1))
            colour[~cells.inner] = (colour[~cells.inner] * BOUNDARY_SHADE).astype(np.uint8)
        if self.style_box.value == "dots":
            return self.server.scene.add_point_cloud(path, centre, colour, point_size=float(cells.size.min()) * 0.5,
                                                     point_shape="circle", point_shading="flat")
        vertices, faces = cube()
        return self.server.scene.add_batched_meshes_simple(
            path, vertices, faces, np.tile([1.0, 0.0, 0.0, 0.0], (len(centre), 1)), centre,
            batched_scales=(cells.size * 0.96).astype(np.float32), batched_colors=colour,
            wireframe=self.style_box.value == "wireframe", opacity=0.3 if self.style_box.value == "boxes" else None,
            cast_shadow=False, receive_shadow=False)

    def draw_accommodation(self) -> Any:
        """The population's accommodation volume as dots coloured by the share, at or above the panel's threshold;
        returns the drawn handle (None: hidden or nothing to draw)."""
        with self._lock:
            self.server.scene.remove_by_name("/accommodation")
            if self.accommodation is None or not self.accommodation_box.value:
                return None
            points, share = self.accommodation
            keep = share >= float(self.accommodation_at.value) / 100.0 - 1e-9
            if not keep.any():
                return None
            return self.server.scene.add_point_cloud("/accommodation", points[keep].astype(np.float32),
                                                     index_colours(share[keep]), point_size=0.6 * self._dot,
                                                     point_shape="circle", point_shading="flat")

    def show_strategy(self, name: str, visible: bool, atlas: int = 0) -> None:
        """Show or hide a strategy's layer (as its panel checkbox does)."""
        self.layer_boxes[(atlas, name)].value = visible
        self.draw()

    # -- answers --------------------------------------------------------------
    def set_effector(self, effector: str) -> None:
        self.effector = effector
        self.set_goal(self.goal)

    def set_policy(self, policy: str) -> None:
        self.policy = policy
        self.selectors = [
            Selector(s.atlas, policy=policy, refine=self.refine) for s in self.scenes  # type: ignore[arg-type]
        ]
        self._planner = None
        for s in self.scenes:
            s.covered.clear()
        self.draw()
        self.set_goal(self.goal)

    def answer(self, k: int, goal: np.ndarray) -> dict[str, Any]:
        """Atlas k's answer for a goal [m] in its own frame: the selector's, or the server's with ``connect``."""
        if self.client is not None:
            reply = self.client.query(self.effector, [float(v) for v in goal], self.refine)
            return {k: v for k, v in reply.items() if k not in ("id", "ok")}
        return self.selectors[k].select(self.effector, goal).to_dict()

    def set_goal(self, goal: np.ndarray) -> list[dict[str, Any]]:
        """Move the goal [m, world frame of the first atlas]: answer it for every atlas and show the answers."""
        goal = np.asarray(goal, float).reshape(3)
        self.goal = goal
        if self.motion is not None:  # a new goal: the motion shown was to the old one
            self.pause()
            self.motion = None
            self._path.remove()
            self._path = None
            self.play_button.disabled = self.frame_slider.disabled = True
            self.motion_box.content = ""
        self.answers = [self.answer(k, goal) for k in range(len(self.scenes))]
        if not np.allclose(self.gizmo.position, goal):
            self.gizmo.position = tuple(goal)
        if not np.allclose(self.goal_box.value, goal):
            # settable at run time
            self.goal_box.value = (float(goal[0]), float(goal[1]), float(goal[2]))  # type: ignore[misc]
        lines = []
        for k, (scene, a) in enumerate(zip(self.scenes, self.answers, strict=True)):
            label = scene.atlas.manifest.get("name", f"atlas {k}")
            if k:
                self.goal_markers[k].position = tuple(goal + scene.offset)
            if not a["reachable"]:
                lines.append(f"**{label}**: unreachable")
                self.goal_markers[k].color = UNREACHABLE
                continue
            names = list(scene.atlas.trees)
            r, g, b = (int(c) for c in scene.colours[names.index(a["strategy"])])
            alt = ", ".join(a["alternatives"]) or "none"
            residual = "n/a" if a["residual"] is None else f"{1000 * a['residual']:.1f} mm"
            passed = (f"  \nhanded over by {a['handover']['from']} (at its limits: "
                      f"{', '.join(a['handover']['limits'])})" if a.get("handover") else "")
            lines.append(f"**{label}**: <span style='color: rgb({r},{g},{b})'>&#9632;</span> **{a['strategy']}**  \n"
                         f"alternatives: {alt}  \nrefined: {a['refined']}, residual {residual}{passed}")
            self.goal_markers[k].color = (r, g, b)
            if scene.shaper is not None and a["posture"] is not None:
                q = posture_vector(scene.shaper.posture_names, scene.shaper.reference_posture(), a["posture"],
                                   a["root"])
                self._pose(scene, scene.shaper.shape(q)[1])
        self.answer_box.content = "\n\n".join(lines)
        return self.answers

    # -- motion -----------------------------------------------------------------
    @property
    def playing(self) -> bool:
        return self.playback.playing

    def plan_motion(self) -> dict[str, Any]:
        """Plan the motion to the goal on the first atlas (its planner, or the server's ``motion``), draw the
        hand's path and show its first frame; returns the motion's summary."""
        self.pause()
        scene = self.scenes[0]
        if scene.shaper is None:
            raise InputError("motion", "this atlas has no body to move")
        try:
            if self.client is not None:
                data = {k: v for k, v in self.client.motion(effector=self.effector,
                                                            goal=[float(v) for v in self.goal]).items()
                                                                if k not in ("id", "ok")}
            else:
                # its own selector: a motion ends in a refined answer, whatever the view shows
                if self._planner is None:
                    self._planner = Planner(Selector(scene.atlas, policy=self.policy))  # type: ignore[arg-type]
                data = self._planner.plan(self.effector, self.goal).to_dict()
        # shown on the panel: the page lives on
        except (MotionError, InputError, ServerError, ServerUnavailable) as exc:
            self.motion_box.content = f"no motion: {exc}"
            return {"error": str(exc)}
        ref, names = scene.shaper.reference_posture(), scene.shaper.posture_names
        frames = data.pop("frames")
        postures = np.array([posture_vector(names, ref, f["posture"], f["root"]) for f in frames])
        path = np.array([f["effector"] for f in frames], float) + scene.offset
        self.motion = {**data, "times": np.array([f["t"] for f in frames]), "postures": postures, "path": path}
        if self._path is not None:
            self._path.remove()
        segments = np.stack([path[:-1], path[1:]], axis=1) if len(path) > 1 else np.stack([path, path], axis=1)
        self._path = self.server.scene.add_line_segments("/atlas0/motion/path", segments, (20, 20, 20), thickness=0.006)
        last = len(postures) - 1
        self.frame_slider.max, self.frame_slider.disabled, self.play_button.disabled = max(last, 1), False, False
        self.motion_box.content = (f"**{data['strategy']}**, {data['outcome']}: {data['duration']:.2f} s, "
                                   f"{len(postures)} frames at {data['rate']:g} Hz  \n{data['waypoints']} stored "
                                   f"postures on the way, {data['held']} frames held")
        self.frame_slider.value = 0  # type: ignore[misc]  # settable at run time
        self.show_frame(0)
        return data

    def show_frame(self, k: int) -> None:
        """Pose the first atlas's body at frame k of the planned motion."""
        if self.motion is None:
            return
        scene = self.scenes[0]
        k = int(np.clip(k, 0, len(self.motion["postures"]) - 1))
        self._pose(scene, scene.shaper.shape(self.motion["postures"][k])[1])
        self.frame = k

    def play(self) -> None:
        """Play the motion at its rate from the slider's frame (from the start when at the end)."""
        if self.motion is None or self.playing:
            return
        last = len(self.motion["postures"]) - 1
        start = 0 if int(self.frame_slider.value) >= last else int(self.frame_slider.value)

        def show(k: int) -> None:
            self.frame_slider.value = k  # type: ignore[misc]  # settable at run time; its update poses the body

        self.playback.start(start, last, float(self.motion["rate"]) * float(self.speed_slider.value), show)

    def pause(self) -> None:
        self.playback.stop()

    def close(self) -> None:
        self.pause()
        self.gate.close()
        self.server.stop()
        if self.client is not None:
            self.client.close()
