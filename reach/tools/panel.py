"""The viewer's page (:mod:`reach.tools.view`): its panel's folders (the goal, the motion, the volumes), the goal's
gizmo and markers, the floor and the camera, each control wired to the viewer; and each atlas's body, drawn from its
collision capsules."""

from __future__ import annotations

from typing import Any

import numpy as np

from oracles.protocol import Furnished, OracleSpec, Shaped
from reach.maps.protocol import POLICIES

BODY = (230, 200, 170)  # skin
FURNITURE = (140, 140, 148)  # a seat, a table: grey
STYLES = ("boxes", "dots", "wireframe")
CELLS = ("inner", "boundary", "both")
SLICE_AXES = ("none", "x", "y", "z")


def build(v: Any) -> None:
    """The panel and the scene's controls of viewer ``v`` (a :class:`reach.tools.view.Viewer`)."""
    gui = v.server.gui
    with gui.add_folder("Goal"):
        v.effector_box = gui.add_dropdown("effector", v.selectors[0].effectors, initial_value=v.effector)
        v.goal_box = gui.add_vector3("goal [m]", tuple(v.goal), step=0.01)
        v.policy_box = gui.add_dropdown("policy", list(POLICIES), initial_value=v.policy, disabled=v.client is not None,
                                        hint="the server's own policy applies with --connect" if v.client else None)
        v.answer_box = gui.add_markdown("")
    with gui.add_folder("Motion"):
        v.plan_button = gui.add_button("plan the reach motion", hint="from the reference posture to the answer (the "
                                       "first atlas)")
        v.play_button = gui.add_button("play / pause", disabled=True)
        v.frame_slider = gui.add_slider("frame", 0, 1, 1, 0, disabled=True)
        v.speed_slider = gui.add_slider("speed", 0.1, 1.0, 0.05, 1.0, hint="playback speed: 1 is real time")
        v.motion_box = gui.add_markdown("")
    with gui.add_folder("Volumes"):
        _volumes(v, gui)
        _layers(v, gui)
    _wire(v)
    _goal(v)


def _volumes(v: Any, gui: Any) -> None:
    """How the volumes are drawn: style, cells, priority, index, slice, and the population's accommodation."""
    v.style_box = gui.add_dropdown("style", list(STYLES), initial_value="boxes")
    v.cells_box = gui.add_dropdown("cells", list(CELLS), initial_value="boundary")
    v.first_box = gui.add_checkbox("first strategy by priority", False, hint="each cell in the colour of the first "
                                   "strategy that holds it (the paper's Figure 8)")
    v.index_box = gui.add_checkbox("reachability index", False, hint="colour the cells of strategies built with "
                                   "`directions: N` by the share of approach directions reached (viridis: dark 0, "
                                   "yellow 1)")
    v.slice_axis = gui.add_dropdown("slice axis", list(SLICE_AXES), initial_value="none")
    box = next(iter(v.scenes[0].atlas.trees.values())).box
    v.slice_at = gui.add_slider("slice at [m]", float(box.lo.min()), float(box.hi.max()), 0.01, 1.0)
    if v.accommodation is not None:
        v.accommodation_box = gui.add_checkbox("accommodation", True, hint="the share of the population's members "
                                               "whose trees hold each point (viridis: dark 0, yellow 1)")
        v.accommodation_at = gui.add_slider("reached by at least [%]", 5, 100, 5, 5)
        v.accommodation_box.on_update(lambda _e: v.draw_accommodation())
        v.accommodation_at.on_update(lambda _e: v.draw_accommodation())


def _layers(v: Any, gui: Any) -> None:
    """A checkbox a strategy, each atlas's under its name: the first of the effector's strategies shown."""
    v.layer_boxes = {}
    for k, scene in enumerate(v.scenes):
        gui.add_markdown(f"**{scene.atlas.manifest.get('name', f'atlas {k}')}**")
        first = next((n for n, t in scene.atlas.trees.items() if t.meta.get("effector") == v.effector), None)
        for i, name in enumerate(scene.atlas.trees):
            r, g, b = (int(c) for c in scene.colours[i])
            box = gui.add_checkbox(name, name == first, hint=f"colour rgb({r}, {g}, {b})")
            box.on_update(lambda _e: v.draw())
            v.layer_boxes[(k, name)] = box


def _typed_goal(v: Any) -> None:
    goal = np.array(v.goal_box.value, float)
    if not np.allclose(goal, v.goal):
        v.set_goal(goal)


def _wire(v: Any) -> None:
    """Each control's update, to the viewer."""
    for handle in (v.style_box, v.cells_box, v.first_box, v.index_box, v.slice_axis, v.slice_at):
        handle.on_update(lambda _e: v.draw())
    v.goal_box.on_update(lambda _e: _typed_goal(v))
    v.plan_button.on_click(lambda _e: v.plan_motion())
    v.play_button.on_click(lambda _e: v.pause() if v.playing else v.play())
    v.frame_slider.on_update(lambda _e: v.show_frame(int(v.frame_slider.value)))
    v.effector_box.on_update(lambda _e: v.set_effector(v.effector_box.value))
    v.policy_box.on_update(lambda _e: v.set_policy(v.policy_box.value))


def _goal(v: Any) -> None:
    """The goal's gizmo, one marker an atlas, the floor, and the camera."""
    scene = v.server.scene
    v.gizmo = scene.add_transform_controls("/goal", scale=0.25, disable_rotations=True, position=tuple(v.goal))
    # One marker per atlas: the gizmo's own for the first, the same goal beside each other body.
    v.goal_markers = [scene.add_icosphere("/goal/marker", radius=0.025, color=(20, 20, 20))]
    v.goal_markers += [scene.add_icosphere(f"/atlas{k}/goal", radius=0.025, color=(20, 20, 20))
                       for k in range(1, len(v.scenes))]
    v.gizmo.on_update(lambda _e: v.set_goal(np.array(v.gizmo.position)))
    middle = 0.5 * v.scenes[-1].offset[1]
    scene.add_grid("/floor", width=3.0, height=3.0 + v.scenes[-1].offset[1], cell_size=0.25,
                   position=(0.2, middle, 0.0))

    @v.server.on_client_connect
    def _camera(client: Any) -> None:  # in front of the body, to its right, looking at the chest
        client.camera.up_direction = (0.0, 0.0, 1.0)
        client.camera.position = (2.2, -1.9 + middle, 1.7)
        client.camera.look_at = (0.2, middle, 1.0)


def add_body(v: Any, k: int, scene: Any) -> None:
    """Atlas k's body: its capsules, one mesh each, moved to postures by their transforms; its furniture."""
    # trimesh only when meshes are read or written
    import trimesh

    spec = next(iter(scene.atlas.trees.values())).meta["oracle"]
    shaper = OracleSpec.from_dict(spec).create()
    if not isinstance(shaper, Shaped):
        return  # an oracle without a body to draw
    scene.shaper = shaper
    names, caps = shaper.shape(shaper.reference_posture())
    for name, cap in zip(names, caps, strict=True):
        length = float(np.linalg.norm(cap[3:6] - cap[:3]))
        mesh = trimesh.creation.capsule(height=max(length, 1e-6), radius=float(cap[6]), count=[12, 12])
        scene.capsules.append(v.server.scene.add_mesh_simple(
            f"/atlas{k}/body/{name}", np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32),
            color=BODY))
    v._pose(scene, caps)
    if isinstance(shaper, Furnished):
        for name, box in zip(*shaper.furniture(), strict=True):
            scene.furniture.append(v.server.scene.add_box(
                f"/atlas{k}/furniture/{name}", color=FURNITURE, dimensions=tuple(2 * box[3:6]),
                wxyz=tuple(box[6:10]), position=tuple(box[:3] + scene.offset), opacity=0.6))
