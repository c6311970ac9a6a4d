"""A recording's link orientations written as a BVH file, on a skeleton given joint by joint: what
makes a BVH walk in any naming from a built-in scenario (see torchik.synthetic.skeletons).

The file is Y-up in centimetres, as most exporters write; torchik's world is z-up, x forward, so a
vector v becomes W^T v with W the reader's Y_UP_TO_Z_UP. Each joint's frame is its link's frame in
those axes, R_bvh = W^T R_link W, so the rest pose (all rotations zero) is the skeleton with every
link frame aligned with the world: the human models' T-pose. Rotations are written as
`Zrotation Xrotation Yrotation` (R = Rz Rx Ry), which is singular only at a 90-degree x rotation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .bvh import Y_UP_TO_Z_UP
from .files import replacing
from .recording import Recording, RecordingError


@dataclass(frozen=True)
class BvhJoint:
    name: str  # the joint's name in the file
    parent: int  # index of the parent joint in the skeleton; -1 for the root
    offset: tuple[float, ...]  # (x, y, z) from the parent joint, metres, torchik's world axes, in the rest pose
    link: str  # the recording's link whose orientation the joint takes


def _zxy_degrees(R: np.ndarray) -> np.ndarray:
    """[...,3,3] rotations -> [...,3] angles (z, x, y) in degrees with R = Rz(z) Rx(x) Ry(y)."""
    x = np.arcsin(np.clip(R[..., 2, 1], -1.0, 1.0))
    z = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    y = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    return np.degrees(np.stack((z, x, y), axis=-1))


def write_bvh(path: str | Path, recording: Recording, skeleton: list[BvhJoint]) -> Path:
    """Write `recording` on `skeleton` (parents before children, the root first and on the recording's
    base link) to `path`; returns the path. RecordingError for a link the recording lacks."""
    index = {name: i for i, name in enumerate(recording.links)}
    missing = [j.link for j in skeleton if j.link not in index]
    if missing:
        raise RecordingError(f"the skeleton's links {missing} are not in the recording; it has {list(recording.links)}")
    if skeleton[0].parent != -1 or skeleton[0].link != recording.base_link:
        raise RecordingError(f"the skeleton's root must be the recording's base link {recording.base_link!r}")
    W = Y_UP_TO_Z_UP
    R = W.T @ recording.orientation[:, [index[j.link] for j in skeleton]] @ W  # [T,J,3,3] in the file's axes
    local = R.copy()
    parents = [j.parent for j in skeleton]
    child = [i for i, p in enumerate(parents) if p >= 0]
    local[:, child] = np.swapaxes(R[:, [parents[i] for i in child]], -1, -2) @ R[:, child]
    angles = _zxy_degrees(local)  # [T,J,3]
    root = recording.base_position @ W / 0.01  # W^T p for row vectors, in centimetres

    lines = ["HIERARCHY"]
    children: dict[int, list[int]] = {i: [] for i in range(len(skeleton))}
    for i in child:
        children[parents[i]].append(i)

    def joint(i: int, depth: int) -> None:
        pad = "\t" * depth
        j = skeleton[i]
        offset = (W.T @ np.asarray(j.offset)) / 0.01
        lines.append(f"{pad}{'ROOT' if j.parent < 0 else 'JOINT'} {j.name}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}")
        position = "Xposition Yposition Zposition " if j.parent < 0 else ""
        lines.append(f"{pad}\tCHANNELS {6 if j.parent < 0 else 3} {position}Zrotation Xrotation Yrotation")
        for c in children[i]:
            joint(c, depth + 1)
        if not children[i]:
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET 0.000000 0.000000 0.000000", f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    joint(0, 0)
    order = []  # the channels' order is the hierarchy's depth-first order

    def visit(i: int) -> None:
        order.append(i)
        for c in children[i]:
            visit(c)

    visit(0)
    lines += ["MOTION", f"Frames: {len(recording.time)}", f"Frame Time: {1.0 / recording.frame_rate:.9f}"]
    values = np.concatenate([root] + [angles[:, i] for i in order], axis=1)
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values]
    path = Path(path)
    with replacing(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    return path
