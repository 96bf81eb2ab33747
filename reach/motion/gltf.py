"""glTF 2.0 files of a motion: a skinned skeleton with the body's capsules, and its animation.

Readable by Blender and three.js (``.glb``: binary; ``.gltf``: JSON with the
data embedded). The scene holds:

* a node per bone (:mod:`oracles.bodies.skeleton`), in glTF's axes (+Y up, +Z
  forward, +X to the body's left; :mod:`reach.motion.rig`), and a node per end (a
  hand's reach point, the toe, the eyes) under its bone; every node is a
  joint of the one skin;
* one mesh, the capsules in the motion's first posture, each vertex moved
  by its capsule's bone alone (weight 1);
* one animation, ``reach``: every bone's rotation and the root's
  translation at each frame (linear samplers; glTF interpolates rotations
  on the sphere), at the times of the motion's frames [s].

The nodes' own transforms are the first frame, which is also the bind pose.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from reach.motion.rig import Rig

FLOAT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5123, 5125  # glTF accessor component types
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963  # buffer view targets
SECTIONS = 8  # a capsule's mesh resolution (trimesh's count per axis)
SKIN_COLOUR = [0.80, 0.62, 0.50, 1.0]


def gltf_document(rig: Rig):  # -> pygltflib.GLTF2
    """The glTF document, its binary data set as its blob."""
    # pygltflib only when a glTF file is written
    import pygltflib as g

    sk = rig.skeleton
    nb, ne = len(sk.bones), len(sk.ends)
    blob = _Blob()
    doc = g.GLTF2(asset=g.Asset(generator="reach", version="2.0"), scene=0)
    first = rig.world(0)
    quats = _quaternions(rig.rotations)  # (T, B, 4) x y z w
    for b, name in enumerate(sk.bones):
        t = rig.root[0] if sk.parents[b] < 0 else rig.offsets[b]
        doc.nodes.append(g.Node(name=name, translation=_floats(t), rotation=_floats(quats[0, b]), children=[]))
    for e, (name, bone, _) in enumerate(sk.ends):
        doc.nodes[bone].children.append(nb + e)
        doc.nodes.append(g.Node(name=name, translation=_floats(rig.ends[e])))
    for b, p in enumerate(sk.parents):
        if p >= 0:
            doc.nodes[p].children.append(b)
    joint_world = np.concatenate([first,
                                  [first[bone] @ _translation(rig.ends[e]) for e, (_, bone, _) in enumerate(sk.ends)]])
    ibm = blob.add(np.linalg.inv(joint_world).transpose(0, 2, 1).reshape(-1, 16).astype(np.float32), None)
    doc.accessors.append(g.Accessor(bufferView=ibm, componentType=FLOAT, count=nb + ne, type="MAT4"))
    doc.skins.append(g.Skin(name="body", joints=list(range(nb + ne)), skeleton=0,
                            inverseBindMatrices=len(doc.accessors) - 1))

    if len(rig.capsules):
        _add_mesh(doc, blob, rig, first)
    doc.scenes.append(g.Scene(nodes=[0] + ([len(doc.nodes) - 1] if len(rig.capsules) else [])))

    times = rig.times.astype(np.float32)
    doc.accessors.append(g.Accessor(bufferView=blob.add(times, None), componentType=FLOAT, count=len(times),
                                    type="SCALAR", min=[float(times[0])], max=[float(times[-1])]))
    clock = len(doc.accessors) - 1
    animation = g.Animation(name="reach")
    tracks = [(b, "rotation", quats[:, b], "VEC4") for b in range(nb)] + [(0, "translation", rig.root, "VEC3")]
    for node, path, values, kind in tracks:
        doc.accessors.append(g.Accessor(bufferView=blob.add(values.astype(np.float32), None), componentType=FLOAT,
                                        count=len(values), type=kind))
        animation.samplers.append(g.AnimationSampler(input=clock, output=len(doc.accessors) - 1,
                                                     interpolation="LINEAR"))
        animation.channels.append(g.AnimationChannel(sampler=len(animation.samplers) - 1,
                                                     target=g.AnimationChannelTarget(node=node, path=path)))
    doc.animations.append(animation)
    doc.bufferViews = blob.views
    doc.buffers.append(g.Buffer(byteLength=len(blob.data)))
    doc.set_binary_blob(bytes(blob.data))
    return doc


def write_gltf(rig: Rig, path: str | Path) -> Path:
    """Write ``.glb`` (binary) or ``.gltf`` (JSON, the data embedded as a data URI)."""
    # pygltflib only when a glTF file is written
    import pygltflib as g

    path = Path(path)
    doc = gltf_document(rig)
    if path.suffix.lower() == ".glb":
        doc.save_binary(str(path))
    else:
        doc.convert_buffers(g.BufferFormat.DATAURI)
        doc.save_json(str(path))
    return path


def _add_mesh(doc, blob: _Blob, rig: Rig, first: np.ndarray) -> None:
    """The capsules as one skinned mesh, in the bind pose (the first frame), and the node that holds it."""
    # pygltflib only when a glTF file is written
    import pygltflib as g

    positions, normals, joints, faces = _capsules(rig, first)
    attributes = g.Attributes()
    for key, data, target in (("POSITION", positions, ARRAY_BUFFER), ("NORMAL", normals, ARRAY_BUFFER)):
        data = data.astype(np.float32)  # min and max as the file holds the values
        doc.accessors.append(g.Accessor(bufferView=blob.add(data, target), componentType=FLOAT, count=len(data),
                                        type="VEC3", min=_floats(data.min(axis=0)), max=_floats(data.max(axis=0))))
        setattr(attributes, key, len(doc.accessors) - 1)
    view = blob.add(np.column_stack([joints, np.zeros((len(joints), 3), int)]).astype(np.uint16), ARRAY_BUFFER)
    doc.accessors.append(g.Accessor(bufferView=view, componentType=UNSIGNED_SHORT, count=len(joints), type="VEC4"))
    attributes.JOINTS_0 = len(doc.accessors) - 1
    weights = np.zeros((len(joints), 4), np.float32)
    weights[:, 0] = 1.0
    doc.accessors.append(g.Accessor(bufferView=blob.add(weights, ARRAY_BUFFER), componentType=FLOAT,
                                    count=len(joints), type="VEC4"))
    attributes.WEIGHTS_0 = len(doc.accessors) - 1
    view = blob.add(faces.reshape(-1).astype(np.uint32), ELEMENT_ARRAY_BUFFER)
    doc.accessors.append(g.Accessor(bufferView=view, componentType=UNSIGNED_INT, count=faces.size, type="SCALAR"))
    doc.materials.append(g.Material(name="skin",
                                    pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=SKIN_COLOUR,
                                        metallicFactor=0.0)))
    doc.meshes.append(g.Mesh(name="capsules",
                             primitives=[g.Primitive(attributes=attributes, indices=len(doc.accessors) - 1,
                                                     material=0)]))
    doc.nodes.append(g.Node(name="body", mesh=0, skin=0))


class _Blob:
    """The binary buffer and its views, each view 4-byte aligned as glTF asks."""

    def __init__(self) -> None:
        # pygltflib only when a glTF file is written
        import pygltflib as g

        self._view = g.BufferView
        self.data = bytearray()
        self.views: list = []

    def add(self, array: np.ndarray, target: int | None) -> int:
        self.data += b"\0" * (-len(self.data) % 4)
        raw = np.ascontiguousarray(array).tobytes()
        self.views.append(self._view(buffer=0, byteOffset=len(self.data), byteLength=len(raw), target=target))
        self.data += raw
        return len(self.views) - 1


def _capsules(rig: Rig, world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The capsules' vertices and normals in the bind pose, each vertex's bone, and the triangles."""
    positions, normals, joints, faces, n = [], [], [], [], 0
    for (ax, ay, az, bx, by, bz, radius), bone in zip(rig.capsules, rig.skeleton.capsule_bones, strict=True):
        a, b = np.array([ax, ay, az]), np.array([bx, by, bz])
        length = float(np.linalg.norm(b - a))
        mesh = trimesh.creation.capsule(height=length, radius=float(radius), count=[SECTIONS, SECTIONS])
        place = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], (b - a) / length) if length > 0 else np.eye(4)
        place[:3, 3] = 0.5 * (a + b)
        place = world[bone] @ place
        positions.append(trimesh.transform_points(mesh.vertices, place))
        normals.append(mesh.vertex_normals @ place[:3, :3].T)
        joints.append(np.full(len(mesh.vertices), bone))
        faces.append(mesh.faces + n)
        n += len(mesh.vertices)
    return np.concatenate(positions), np.concatenate(normals), np.concatenate(joints), np.concatenate(faces)


def _quaternions(rotations: np.ndarray) -> np.ndarray:
    """(T, B, 4) unit quaternions (x, y, z, w) of rotations (T, B, 3, 3), each bone's kept on one hemisphere frame to
    frame."""
    t, b = rotations.shape[:2]
    q = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(t, b, 4)
    for k in range(1, t):
        q[k] *= np.where(np.sum(q[k] * q[k - 1], axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return q


def _translation(v: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def _floats(v: np.ndarray) -> list[float]:
    return [float(x) for x in v]
