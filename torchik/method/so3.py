"""Rotations as batched tensors: hat, vee, skew part, exponential and logarithm, projection.

All functions take tensors with any leading batch shape `[...]` and keep it.
Rotation matrices map a frame's coordinates to the world's (`p_world = R @ p_frame`).
"""

from __future__ import annotations

import torch

_HAT_BASIS: dict[tuple[torch.dtype, torch.device], torch.Tensor] = {}
_IDENTITY: dict[tuple[torch.dtype, torch.device], torch.Tensor] = {}


def identity(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The 3x3 identity, made once per dtype and device (the step uses it several times; read only)."""
    key = (dtype, torch.device(device))
    if key not in _IDENTITY:
        _IDENTITY[key] = torch.eye(3, dtype=dtype, device=device)
    return _IDENTITY[key]


def sum3(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """x summed over a dimension of size 3, as two additions of its slices: torch's CPU reduction
    over one innermost dimension this short is an order of magnitude slower (the timing:
    experiments/speed_history.md). [..., 3, ...] -> [..., ...]"""
    a, b, c = x.unbind(dim)
    return (a + b).add_(c)


def gram_deviation(R: torch.Tensor) -> torch.Tensor:
    """The six distinct entries of R^T R - I: its diagonal, then the (0,1), (0,2), (1,2) entries,
    from dot products of R's columns (a batched product of 3x3 matrices costs twice as much on a
    CPU). R: [..., 3, 3] -> [..., 6]"""
    c0, c1, c2 = R.unbind(-1)
    dots = [sum3(a * b) for a, b in ((c0, c0), (c1, c1), (c2, c2), (c0, c1), (c0, c2), (c1, c2))]
    deviation = torch.stack(dots, -1)
    deviation[..., :3] -= 1.0
    return deviation


def gram_deviation_norm(deviation: torch.Tensor) -> torch.Tensor:
    """||R^T R - I|| (Frobenius) from `gram_deviation`'s six entries [..., 6] -> [...]"""
    square = deviation.square()
    return (square[..., :3].sum(-1) + 2 * square[..., 3:].sum(-1)).sqrt()


def hat_basis(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """[3,9]: row i is hat(e_i) flattened, so that hat(w).flatten() = w @ basis (exact: one term each)."""
    key = (dtype, device)
    if key not in _HAT_BASIS:
        E = torch.zeros(3, 3, 3, dtype=dtype, device=device)
        E[0, 2, 1], E[0, 1, 2] = 1, -1
        E[1, 0, 2], E[1, 2, 0] = 1, -1
        E[2, 1, 0], E[2, 0, 1] = 1, -1
        _HAT_BASIS[key] = E.reshape(3, 9)
    return _HAT_BASIS[key]


def hat(w: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix of a vector, `hat(w) @ x == cross(w, x)`.

    w: [..., 3] -> [..., 3, 3]
    """
    return (w @ hat_basis(w.dtype, w.device)).reshape(w.shape[:-1] + (3, 3))


def vee(S: torch.Tensor) -> torch.Tensor:
    """Vector of a skew-symmetric matrix, inverse of `hat`; reads only the lower triangle.

    S: [..., 3, 3] -> [..., 3]
    """
    return torch.stack((S[..., 2, 1], S[..., 0, 2], S[..., 1, 0]), dim=-1)


def skew_part(A: torch.Tensor) -> torch.Tensor:
    """sk(A) = (A - A^T) / 2.

    A: [..., 3, 3] -> [..., 3, 3]
    """
    return 0.5 * (A - A.transpose(-1, -2))


def skew_vee(A: torch.Tensor) -> torch.Tensor:
    """sk(A)^vee, the vector of the skew-symmetric part of A (the method's orientation error).

    For a rotation `A = exp(hat(theta * u))` this is `sin(theta) * u`.
    A: [..., 3, 3] -> [..., 3]
    """
    return 0.5 * torch.stack(
        (A[..., 2, 1] - A[..., 1, 2], A[..., 0, 2] - A[..., 2, 0], A[..., 1, 0] - A[..., 0, 1]), dim=-1
    )


def exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of a rotation vector (Rodrigues' formula).

    w: [..., 3] -> [..., 3, 3]
    """
    theta = torch.linalg.vector_norm(w, dim=-1, keepdim=True).unsqueeze(-1)
    # sin(t)/t = sinc(t/pi) and (1 - cos t)/t^2 = sinc(t/2pi)^2 / 2, both exact at t = 0
    a = torch.sinc(theta * (1.0 / torch.pi))
    b = torch.sinc(theta * (0.5 / torch.pi)).square()
    K = hat(w)
    return torch.addcmul(torch.addcmul(identity(w.dtype, w.device), a, K), b, K @ K, value=0.5)


def axis_angle(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation about unit axes by angles.

    axis: [..., 3] (unit), angle: [...] -> [..., 3, 3]
    """
    K = hat(axis)
    s = torch.sin(angle)[..., None, None]
    c = torch.cos(angle)[..., None, None]
    eye = identity(axis.dtype, axis.device)
    return eye + s * K + (1.0 - c) * (K @ K)


def log(R: torch.Tensor) -> torch.Tensor:
    """Rotation vector of a rotation matrix, angle in [0, pi].

    R: [..., 3, 3] -> [..., 3]
    """
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0).clamp(-1.0, 1.0)
    theta = torch.arccos(cos)
    v = skew_vee(R)  # sin(theta) * u
    sin = torch.sin(theta)
    small = theta < 1e-6
    near_pi = theta > torch.pi - 1e-3
    scale = torch.where(small, 1.0 + theta * theta / 6.0, theta / torch.where(small, torch.ones_like(sin), sin))
    w = v * scale.unsqueeze(-1)
    if bool(near_pi.any()):
        # Near pi, sin(theta) vanishes; read the axis from the symmetric part instead:
        # (R + R^T)/2 = cos(theta) I + (1 - cos(theta)) u u^T.
        eye = identity(R.dtype, R.device)
        B = (0.5 * (R + R.transpose(-1, -2)) - cos[..., None, None] * eye) / (1.0 - cos)[..., None, None]
        col = B.diagonal(dim1=-2, dim2=-1).argmax(-1)
        u = torch.gather(B, -1, col[..., None, None].expand(B.shape[:-1] + (1,))).squeeze(-1)
        u = u / u.norm(dim=-1, keepdim=True)
        # Choose the sign that agrees with the (small) skew part.
        sign = torch.where((u * v).sum(-1, keepdim=True) < 0, -1.0, 1.0)
        w = torch.where(near_pi.unsqueeze(-1), sign * u * theta.unsqueeze(-1), w)
    return w


def project(A: torch.Tensor) -> torch.Tensor:
    """Nearest rotation matrix in the Frobenius norm (polar decomposition through the SVD).

    A: [..., 3, 3] -> [..., 3, 3]
    """
    U, _, Vh = torch.linalg.svd(A)
    d = torch.sign(torch.linalg.det(U @ Vh))
    D = torch.ones(A.shape[:-1], dtype=A.dtype, device=A.device)
    D[..., 2] = d
    return (U * D.unsqueeze(-2)) @ Vh


def rpy_to_matrix(rpy: torch.Tensor) -> torch.Tensor:
    """URDF roll-pitch-yaw (fixed axes x, y, z) to a rotation matrix, `Rz(yaw) Ry(pitch) Rx(roll)`.

    rpy: [..., 3] -> [..., 3, 3]
    """
    r, p, y = rpy.unbind(-1)
    cr, sr, cp, sp, cy, sy = torch.cos(r), torch.sin(r), torch.cos(p), torch.sin(p), torch.cos(y), torch.sin(y)
    return torch.stack(
        (
            cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
            -sp, cp * sr, cp * cr,
        ),
        dim=-1,
    ).reshape(rpy.shape[:-1] + (3, 3))


def matrix_to_rpy(R: torch.Tensor) -> torch.Tensor:
    """The inverse of `rpy_to_matrix`: roll, pitch, yaw (rad) with R = Rz(yaw) Ry(pitch) Rx(roll), pitch
    in [-pi/2, pi/2]. At pitch +-pi/2 (gimbal lock) roll and yaw turn about one axis: roll is 0 and
    yaw carries their sum (or difference).

    R: [..., 3, 3] -> [..., 3]
    """
    cos_pitch = torch.hypot(R[..., 0, 0], R[..., 1, 0])
    pitch = torch.atan2(-R[..., 2, 0], cos_pitch)  # accurate near +-pi/2, where asin is not
    locked = cos_pitch < 1e-12
    roll = torch.where(locked, torch.zeros_like(pitch), torch.atan2(R[..., 2, 1], R[..., 2, 2]))
    yaw = torch.where(locked, torch.atan2(-R[..., 0, 1], R[..., 1, 1]), torch.atan2(R[..., 1, 0], R[..., 0, 0]))
    return torch.stack((roll, pitch, yaw), dim=-1)


def random_rotation(shape: tuple[int, ...], generator: torch.Generator | None = None,
                    dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Rotations drawn uniformly on SO(3) (normalised Gaussian quaternions).

    shape: batch shape -> [*shape, 3, 3]
    """
    q = torch.randn(tuple(shape) + (4,), generator=generator, dtype=dtype)
    q = q / q.norm(dim=-1, keepdim=True)
    return quaternion_to_matrix(q)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternion (w, x, y, z) to rotation matrix.

    q: [..., 4] -> [..., 3, 3]
    """
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        (
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ),
        dim=-1,
    ).reshape(q.shape[:-1] + (3, 3))
