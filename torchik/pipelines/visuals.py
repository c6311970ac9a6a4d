"""The visual shapes of a URDF (boxes, cylinders, spheres, meshes) and how rerun draws them: the
body of a rerun recording (rrd.py). Read once per recording, at build time."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import torch

from ..errors import InputError, optional
from ..method import so3
from ..method.kinematics import read_urdf

if TYPE_CHECKING:
    import rerun as rr
else:
    rr = optional("rerun", "viz", "writing rerun recordings")


@dataclass(frozen=True)
class Visual:
    """One URDF <visual> of a link: kind 'box' (size: full extents [3]), 'cylinder' (size: radius,
    length; axis z), 'sphere' (size: radius,) or 'mesh' (mesh: the file, size: scale [3]); its
    origin in the link frame (translation [3], quaternion [4] x,y,z,w); rgba or None."""

    kind: str
    size: tuple[float, ...]
    translation: tuple[float, ...]  # [3]
    quaternion: tuple[float, ...]  # [4] x, y, z, w
    mesh: Path | None = None
    rgba: tuple[float, float, float, float] | None = None


def visuals(urdf: str | Path) -> dict[str, list[Visual]]:
    """The visual shapes of a URDF (a file or its XML text), by link name. Mesh files given as
    package://PACKAGE/... are looked for in a PACKAGE folder above the URDF's; a mesh that cannot
    be found is left out with a warning naming it (the skeleton and frames still show the link)."""
    robot, where = read_urdf(urdf)
    folder = Path(where).parent if Path(where).is_file() else Path.cwd()
    shapes: dict[str, list[Visual]] = {}
    for link in robot.links:  # build time: a Python walk over the URDF's links is fine
        for visual in link.visuals:
            geometry, origin = visual.geometry, visual.origin
            xyz = tuple(float(v) for v in (origin.xyz if origin is not None and origin.xyz is not None else (0, 0, 0)))
            rpy = torch.tensor(origin.rpy if origin is not None and origin.rpy is not None else (0.0, 0.0, 0.0),
                               dtype=torch.float64)
            quaternion = tuple(quaternion_xyzw(so3.rpy_to_matrix(rpy)).tolist())
            material = getattr(visual, "material", None)
            color = getattr(material, "color", None)
            rgba = tuple(color.rgba) if color is not None and color.rgba is not None else None
            kind = type(geometry).__name__.lower()
            if kind == "box":
                size = tuple(float(v) for v in geometry.size)
            elif kind == "cylinder":
                size = (float(geometry.radius), float(geometry.length))
            elif kind == "sphere":
                size = (float(geometry.radius),)
            elif kind == "mesh":
                mesh = find_mesh(geometry.filename, folder)
                if mesh is None:
                    warnings.warn(f"{where}: link {link.name!r}: mesh {geometry.filename} not found; "
                                  f"the recording shows the link without it", stacklevel=2)
                    continue
                scale = tuple(float(v) for v in geometry.scale) if geometry.scale is not None else (1.0, 1.0, 1.0)
                shapes.setdefault(link.name, []).append(Visual("mesh", scale, xyz, quaternion, mesh, rgba))
                continue
            else:
                raise InputError(f"{where}: link {link.name!r} has a visual of unknown type {kind!r}")
            shapes.setdefault(link.name, []).append(Visual(kind, size, xyz, quaternion, None, rgba))
    return shapes


def log_visuals(rec: rr.RecordingStream, path: str, shapes: Sequence[Visual], color: tuple[int, int, int]) -> None:
    """A link's visual shapes at `path`, static, in the link frame: primitives of one kind in one
    archetype; each mesh at path/mesh<k> with its origin and scale."""
    rgba = lambda v: [int(255 * c) for c in v.rgba] if v.rgba is not None else [*color, 255]  # noqa: E731
    by_kind: dict[str, list[Visual]] = {}
    for v in shapes:
        by_kind.setdefault(v.kind, []).append(v)
    def common(vs: list[Visual]) -> dict[str, Any]:
        return dict(centers=[v.translation for v in vs], quaternions=[v.quaternion for v in vs],
                    colors=[rgba(v) for v in vs])

    if "box" in by_kind:
        vs = by_kind["box"]
        rec.log(path, rr.Boxes3D(half_sizes=[[s / 2 for s in v.size] for v in vs], **common(vs)), static=True)
    if "cylinder" in by_kind:
        vs = by_kind["cylinder"]
        rec.log(path, rr.Cylinders3D(radii=[v.size[0] for v in vs], lengths=[v.size[1] for v in vs], **common(vs)),
                static=True)
    if "sphere" in by_kind:
        vs = by_kind["sphere"]
        rec.log(path, rr.Ellipsoids3D(half_sizes=[[v.size[0]] * 3 for v in vs], **common(vs)), static=True)
    for k, v in enumerate(by_kind.get("mesh", ())):
        rec.log(f"{path}/mesh{k}", rr.Transform3D(translation=v.translation, quaternion=rr.Quaternion(xyzw=v.quaternion),
                                                  scale=v.size),
                rr.Asset3D(path=v.mesh, albedo_factor=rgba(v)), static=True)


def find_mesh(filename: str, folder: Path) -> Path | None:
    """A URDF mesh reference as a file: package://PACKAGE/REST in a folder PACKAGE at or above
    `folder` (or beside one), file://PATH, or a path relative to `folder`."""
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://"):].partition("/")
        for above in (folder, *folder.parents):
            candidates = [above / package / rest] + ([above / rest] if above.name == package else [])
            found = [c for c in candidates if c.is_file()]
            if found:
                return found[0]
        return None
    path = Path(filename[len("file://"):] if filename.startswith("file://") else filename)
    path = path if path.is_absolute() else folder / path
    return path if path.is_file() else None


def quaternion_xyzw(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [...,3,3] to unit quaternions [...,4] (x, y, z, w), rerun's order.

    Each row of `candidates` is 4 q_k q for one k; the row with the largest diagonal entry 4 q_k^2
    is the one whose normalisation is well conditioned (Shepperd's method)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = (r.unbind(-1) for r in R.unbind(-2))
    candidates = torch.stack((
        torch.stack((1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01), -1),  # 4w (w, x, y, z)
        torch.stack((m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20), -1),  # 4x (w, x, y, z)
        torch.stack((m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21), -1),  # 4y
        torch.stack((m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22), -1),  # 4z
    ), -2)  # [...,4,4]
    best = candidates.diagonal(dim1=-2, dim2=-1).argmax(-1)  # [...]
    q = candidates.gather(-2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return q[..., [1, 2, 3, 0]]
