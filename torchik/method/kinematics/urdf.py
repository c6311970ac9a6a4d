"""Reading a URDF and compiling it into a `KinematicTree`: the frozen, device-free description of
the tree that every tensor of a `KinematicModel` is derived from.

The tree is a *skeleton* of frames (the base link and the child frame of every movable joint)
ordered by depth, with the constant transform from each frame's parent to its joint (in float64:
pytorch-kinematics' own transforms go through float32). Every other link is fixed to a skeleton
frame, its *anchor*, at a constant offset. Plain Python and NumPy, built once.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import io
import sys
import threading
from collections import deque
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import Mapping, NamedTuple

import numpy as np
import torch

from ...errors import ModelError
from .. import so3

MOVABLE = ("revolute", "continuous")


@dataclass(frozen=True, eq=False)
class KinematicTree:
    """A URDF compiled once: F skeleton frames (sorted by depth, frame 0 the base), n movable
    joints (in URDF order, the order of `s`), N links. Arrays are read-only, float64.

    frame_parent [F] (-1 for the base), frame_joint [F] (the joint moving each frame, -1 for the
    base), joint_frame [n] (each joint's child frame); levels: (start, stop, parents) per depth
    below the base, each level a contiguous slice of frames; jumps: the pointer-jumping schedule,
    frame F being the world, its own parent (after round r every frame is composed with its 2^r-th
    ancestor); axes [F,3] unit joint axes in their frames (zero for the base); frame_rotation
    [F,3,3], frame_position [F,3] each joint frame (at zero angle) in its parent frame;
    link_anchor [N], link_rotation [N,3,3], link_position [N,3] every link in its anchor frame;
    ancestor [F,n] 1 where joint j moves frame f; joint_parents [n] each joint's nearest ancestor
    joint (-1 where only the base lies above it); lower, upper [n] limits (infinite when none).
    """

    name: str | None
    source: str
    base_link: str
    link_names: tuple[str, ...]
    joint_names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    frame_parent: tuple[int, ...]
    frame_joint: tuple[int, ...]
    joint_frame: tuple[int, ...]
    levels: tuple[tuple[int, int, tuple[int, ...]], ...]
    jumps: tuple[tuple[int, ...], ...]
    axes: np.ndarray
    frame_rotation: np.ndarray
    frame_position: np.ndarray
    link_anchor: tuple[int, ...]
    link_rotation: np.ndarray
    link_position: np.ndarray
    ancestor: np.ndarray
    joint_parents: tuple[int, ...]
    link_mass: np.ndarray
    link_com: np.ndarray
    link_inertia: np.ndarray

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)

    @property
    def n_frames(self) -> int:
        return len(self.frame_parent)

    @cached_property
    def link_index(self) -> Mapping[str, int]:
        """Each link's row in link_names."""
        return MappingProxyType({name: i for i, name in enumerate(self.link_names)})

    def __getstate__(self) -> dict:
        """For pickling (a model sent to another process): the cached link_index, a mapping proxy that
        cannot be pickled, is left out and made again on first use."""
        return {name: value for name, value in self.__dict__.items() if name != "link_index"}

    def same_topology(self, other: "KinematicTree") -> bool:
        """True when both trees have the same joints, links, skeleton and axes (dimensions may differ)."""
        return (other.joint_names == self.joint_names and other.link_names == self.link_names
                and other.frame_parent == self.frame_parent and np.allclose(other.axes, self.axes))


PARSER = "torchik._urdf_parser_py"  # the name pytorch-kinematics' parser is loaded under
_LOADING = threading.Lock()  # two threads building their first models load it once


@functools.cache
def urdf_class():
    """pytorch-kinematics' URDF parser (its `urdf_parser_py` subpackage), loaded on its own under
    PARSER. `import pytorch_kinematics.urdf_parser_py` would first run the package's `__init__`,
    which imports its IK solvers, SDF tools and matplotlib: far longer than the parser's own import
    (lxml, yaml), and a third of what building a model cost (experiments/speed_history.md).
    The subpackage imports only itself (relative imports), so it loads the same under another name.
    Where the package was imported before the first model is built, its own parser is used."""
    if "pytorch_kinematics" in sys.modules:
        from pytorch_kinematics.urdf_parser_py.urdf import URDF

        return URDF
    with _LOADING:
        return _load_parser()


def _load_parser():
    """The URDF class of the parser loaded under PARSER (loaded now, unless it was)."""
    if PARSER not in sys.modules:
        package = importlib.util.find_spec("pytorch_kinematics")
        if package is None or not package.submodule_search_locations:
            raise ModelError("pytorch-kinematics is not installed: `pip install pytorch-kinematics` (it parses URDFs)")
        where = Path(package.submodule_search_locations[0]) / "urdf_parser_py"
        spec = importlib.util.spec_from_file_location(PARSER, where / "__init__.py",
                                                      submodule_search_locations=[str(where)])
        module = importlib.util.module_from_spec(spec)
        sys.modules[PARSER] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:  # nothing half-loaded stays for the next try
            for name in [name for name in sys.modules if name == PARSER or name.startswith(PARSER + ".")]:
                del sys.modules[name]
            raise
    return sys.modules[PARSER + ".urdf"].URDF


def read_urdf(source: str | Path):
    """Parse a URDF file (or XML text) with pytorch-kinematics' parser; errors name the file.
    Returns (the parsed robot, where: the file's path or '<URDF text>')."""
    URDF = urdf_class()
    if isinstance(source, Path) or (isinstance(source, str) and not source.lstrip().startswith("<")):
        path = Path(source)
        if not path.is_file():
            raise ModelError(f"URDF file not found: {path}")
        text, where = path.read_text(), str(path)
    else:
        text, where = str(source), "<URDF text>"
    # The parser prints a line for every tag it does not know (sensors, gazebo); keep them quiet.
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        try:
            robot = URDF.from_xml_string(text)
        except Exception as exc:  # the parser raises bare XML and assertion errors
            raise ModelError(f"{where}: not a valid URDF ({type(exc).__name__}: {exc})") from exc
    if not robot.links:
        raise ModelError(f"{where}: the URDF has no links")
    return robot, where


def load_tree(source: str | Path) -> KinematicTree:
    """Read and compile a URDF file (or its XML text). Raises ModelError naming the file and problem."""
    return compile_tree(*read_urdf(source))


def compile_tree(robot, where: str) -> KinematicTree:
    """Compile a parsed URDF (`read_urdf`) into a KinematicTree; `where` names it in errors."""
    links = tuple(link.name for link in robot.links)
    joints = list(robot.joints)
    children, base_link = _children(links, joints, where)
    walk = _walk(children, base_link, where)
    if len(walk.visited) != len(links):
        raise ModelError(f"{where}: links not connected to the root: {sorted(set(links) - set(walk.visited))}")

    # Joint order: as the movable joints appear in the URDF (what other tools show users).
    joint_names = tuple(j.name for j in joints if j.type in MOVABLE)
    joint_index = {name: i for i, name in enumerate(joint_names)}
    # Skeleton frames sorted by depth so that each tree level is one contiguous slice.
    order = sorted(range(len(walk.parent)), key=lambda f: (walk.depth[f], f))
    new_index = {old: new for new, old in enumerate(order)}
    parent = tuple(new_index[walk.parent[f]] if f else -1 for f in order)
    frame_joint = tuple(joint_index[walk.joint_name[f]] if f else -1 for f in order)
    joint_frame = [0] * len(joint_names)
    for f, j in enumerate(frame_joint):
        if j >= 0:
            joint_frame[j] = f
    ancestor = _ancestors(parent, frame_joint, len(joint_names))
    lower, upper = _limits(joints, joint_names)
    return KinematicTree(
        name=robot.name, source=where, base_link=base_link, link_names=links, joint_names=joint_names,
        lower=lower, upper=upper, frame_parent=parent, frame_joint=frame_joint, joint_frame=tuple(joint_frame),
        levels=_levels(parent, [walk.depth[f] for f in order]), jumps=_jumps(parent),
        axes=_frozen(np.stack([walk.axis[f] for f in order])),
        frame_rotation=_frozen(np.stack([walk.offset[f][0] for f in order])),
        frame_position=_frozen(np.stack([walk.offset[f][1] for f in order])),
        link_anchor=tuple(new_index[walk.frame_of_link[n]] for n in links),
        link_rotation=_frozen(np.stack([walk.link_offset[n][0] for n in links])),
        link_position=_frozen(np.stack([walk.link_offset[n][1] for n in links])),
        ancestor=_frozen(ancestor), joint_parents=_joint_parents(ancestor, joint_frame),
        **_mass_properties(robot, where),
    )


def _mass_properties(robot, where: str) -> dict[str, np.ndarray]:
    """link_mass [N], link_com [N,3] (the <inertial> origin, in the link's frame) and link_inertia
    [N,3,3] (the <inertia> about the centre of mass, turned from the inertial frame, the <inertial>
    origin's rpy, to the link's axes: R I R^T) of the parsed URDF's links."""
    n = len(robot.links)
    mass, com, inertia = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3, 3))
    for i, link in enumerate(robot.links):
        inertial = getattr(link, "inertial", None)
        if inertial is None:
            continue
        m = float(inertial.mass or 0.0)
        if not (m >= 0.0 and np.isfinite(m)):
            raise ModelError(f"{where}: link {link.name!r} has mass {m}; a mass is a finite number >= 0")
        mass[i] = m
        R, com[i] = _origin(inertial.origin)
        I = _inertia_matrix(inertial.inertia)
        if not np.all(np.isfinite(I)):
            raise ModelError(f"{where}: link {link.name!r} has a non-finite <inertia>")
        inertia[i] = R @ I @ R.T
    return dict(link_mass=_frozen(mass), link_com=_frozen(com), link_inertia=_frozen(inertia))


def _inertia_matrix(inertia) -> np.ndarray:
    """A URDF <inertia> (ixx, ixy, ixz, iyy, iyz, izz; absent: zero) as a symmetric [3,3]."""
    if inertia is None:
        return np.zeros((3, 3))
    value = lambda name: float(getattr(inertia, name, 0.0) or 0.0)  # noqa: E731
    xy, xz, yz = value("ixy"), value("ixz"), value("iyz")
    return np.array([[value("ixx"), xy, xz], [xy, value("iyy"), yz], [xz, yz, value("izz")]])


def _frozen(a: np.ndarray) -> np.ndarray:
    """`a`, read-only from now on (the tree is shared by every model derived from it)."""
    a.flags.writeable = False
    return a


def _children(links: tuple[str, ...], joints: list, where: str) -> tuple[dict[str, list], str]:
    """Each link's child joints, and the root link; checks that the joints form one tree."""
    by_child = {}
    children: dict[str, list] = {name: [] for name in links}
    for j in joints:
        if j.parent not in children or j.child not in children:
            raise ModelError(f"{where}: joint {j.name!r} connects unknown links {j.parent!r} -> {j.child!r}")
        if j.type not in MOVABLE + ("fixed",):
            raise ModelError(
                f"{where}: joint {j.name!r} has type {j.type!r}; torchik supports revolute, continuous and fixed joints"
            )
        if j.child in by_child:
            raise ModelError(f"{where}: link {j.child!r} has two parent joints; a URDF must be a tree")
        by_child[j.child] = j
        children[j.parent].append(j)
    roots = [name for name in links if name not in by_child]
    if len(roots) != 1:
        raise ModelError(f"{where}: expected one root link, found {roots}")
    return children, roots[0]


class _Walk(NamedTuple):
    """The skeleton in breadth-first order (before sorting by depth), and every link's anchor."""

    visited: list[str]
    frame_of_link: dict[str, int]
    link_offset: dict[str, tuple[np.ndarray, np.ndarray]]  # (R [3,3], p [3]) link in its anchor frame
    parent: list[int]
    depth: list[int]
    joint_name: list[str | None]
    offset: list[tuple[np.ndarray, np.ndarray]]  # (R, p) joint frame (at zero angle) in its parent frame
    axis: list[np.ndarray]


def _walk(children: dict[str, list], base_link: str, where: str) -> _Walk:
    """Breadth-first walk: every link gets its anchor (skeleton frame) and offset from it."""
    identity = (np.eye(3), np.zeros(3))
    w = _Walk(visited=[], frame_of_link={base_link: 0}, link_offset={base_link: identity}, parent=[-1], depth=[0],
              joint_name=[None], offset=[identity], axis=[np.zeros(3)])
    order = deque([base_link])
    while order:
        parent = order.popleft()
        w.visited.append(parent)
        Ra, pa = w.link_offset[parent]  # parent link in its anchor frame
        for j in children[parent]:
            Rj, pj = _origin(j.origin)
            R_in_anchor, p_in_anchor = Ra @ Rj, pa + Ra @ pj
            if j.type == "fixed":
                w.frame_of_link[j.child] = w.frame_of_link[parent]
                w.link_offset[j.child] = (R_in_anchor, p_in_anchor)
            else:
                axis = np.array(j.axis if j.axis is not None else [1.0, 0.0, 0.0], dtype=np.float64)
                if np.linalg.norm(axis) < 1e-12:
                    raise ModelError(f"{where}: joint {j.name!r} has a zero axis")
                w.frame_of_link[j.child] = len(w.parent)
                w.link_offset[j.child] = (np.eye(3), np.zeros(3))
                w.parent.append(w.frame_of_link[parent])
                w.depth.append(w.depth[w.frame_of_link[parent]] + 1)
                w.joint_name.append(j.name)
                w.offset.append((R_in_anchor, p_in_anchor))
                w.axis.append(axis / np.linalg.norm(axis))
            order.append(j.child)
    return w


def _origin(origin) -> tuple[np.ndarray, np.ndarray]:
    """URDF <origin> as (R [3,3], p [3]) in float64."""
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = np.array(origin.xyz if origin.xyz is not None else [0, 0, 0], dtype=np.float64)
    rpy = np.array(origin.rpy if origin.rpy is not None else [0, 0, 0], dtype=np.float64)
    return so3.rpy_to_matrix(torch.from_numpy(rpy)).numpy(), xyz


def _limits(joints: list, joint_names: tuple[str, ...]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Lower and upper limits [n]; infinite for continuous joints and joints without limits."""
    limits = {j.name: j.limit for j in joints}
    types = {j.name: j.type for j in joints}
    lower, upper = [], []
    for name in joint_names:
        lim = limits[name]
        if types[name] == "continuous" or lim is None or lim.lower is None or lim.upper is None:
            lower.append(-np.inf)
            upper.append(np.inf)
        else:
            lower.append(float(lim.lower))
            upper.append(float(lim.upper))
    return tuple(lower), tuple(upper)


def _levels(parent: tuple[int, ...], depth: list[int]) -> tuple[tuple[int, int, tuple[int, ...]], ...]:
    """(start, stop, parents) of each depth below the base, frames sorted by depth."""
    levels = []
    for d in range(1, max(depth) + 1):
        members = [i for i in range(len(parent)) if depth[i] == d]
        levels.append((members[0], members[-1] + 1, tuple(parent[i] for i in members)))
    return tuple(levels)


def _jumps(parent: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    """The pointer-jumping schedule: each round's ancestor of every frame and of the world (frame F)."""
    n_frames = len(parent)
    jumps, up = [], np.array([p if p >= 0 else n_frames for p in parent] + [n_frames])
    while not np.all(up == n_frames):
        jumps.append(tuple(int(u) for u in up))
        up = up[up]
    return tuple(jumps)


def _ancestors(parent: tuple[int, ...], frame_joint: tuple[int, ...], n_dof: int) -> np.ndarray:
    """[F, n] 1 where joint j lies on the path from the base to skeleton frame f."""
    mask = np.zeros((len(parent), n_dof))
    for f in range(len(parent)):
        g = f
        while g > 0:
            mask[f, frame_joint[g]] = 1.0
            g = parent[g]
    return mask


def _joint_parents(ancestor: np.ndarray, joint_frame: list[int]) -> tuple[int, ...]:
    """Each joint's nearest ancestor joint (-1 where only the base lies above it): the joints' own
    tree, which the structured QP solve eliminates leaves first."""
    above = ancestor[joint_frame]  # [n,n] ancestor-or-self joints of each joint
    depth = above.sum(1)
    parents = []
    for j in range(len(joint_frame)):
        candidates = [k for k in np.flatnonzero(above[j]) if k != j]
        parents.append(int(max(candidates, key=lambda k: depth[k])) if candidates else -1)
    return tuple(parents)
