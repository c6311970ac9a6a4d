"""Measured targets for one time step, and their cleaning at the tracker's boundary.

A step is driven by `n_p` position targets (world position and linear velocity of a link
origin) and `n_o` orientation targets (world rotation and world angular velocity of a link),
as in the paper: a position target on the base link and an orientation target on every
tracked link.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import InputError
from . import so3


@dataclass(frozen=True)
class Targets:
    """Targets at one instant for a batch of B subjects.

    position: [B,n_p,3] m, world; linear_velocity: [B,n_p,3] m/s, world;
    rotation: [B,n_o,3,3] link-to-world; angular_velocity: [B,n_o,3] rad/s, world.
    """

    position: torch.Tensor
    linear_velocity: torch.Tensor
    rotation: torch.Tensor
    angular_velocity: torch.Tensor

    @property
    def batch(self) -> int:
        return self.rotation.shape[0] if self.rotation.numel() else self.position.shape[0]

    def to(self, dtype=None, device=None) -> "Targets":
        return Targets(*(t.to(dtype=dtype, device=device) for t in vars(self).values()))



@dataclass(frozen=True)
class CleanTargets:
    """Targets ready for a step, with what cleaning did.

    position_valid: [B,n_p] bool; orientation_valid: [B,n_o] bool (NaN or Inf: dropped this step);
    dropped: [B] targets dropped; projected: [B] rotations projected back onto SO(3);
    all_valid: no target was dropped.
    """

    targets: Targets
    position_valid: torch.Tensor
    orientation_valid: torch.Tensor
    dropped: torch.Tensor
    projected: torch.Tensor
    all_valid: bool = True


def check_targets(targets: Targets, n_position: int, n_orientation: int, dtype: torch.dtype,
                  device: torch.device, batch: int | None = None) -> None:
    """Shapes, dtype and device, with a message that says what was expected."""
    B = batch if batch is not None else targets.batch
    expected = dict(position=(B, n_position, 3), linear_velocity=(B, n_position, 3),
                    rotation=(B, n_orientation, 3, 3), angular_velocity=(B, n_orientation, 3))
    for name, shape in expected.items():
        t = getattr(targets, name)
        if not isinstance(t, torch.Tensor) or tuple(t.shape) != shape:
            got = list(t.shape) if isinstance(t, torch.Tensor) else type(t).__name__
            raise InputError(f"targets.{name}: expected shape {list(shape)}, got {got}")
        if t.dtype != dtype or t.device != device:
            raise InputError(f"targets.{name}: expected {dtype} on {device}, got {t.dtype} on {t.device}")


def _worst(targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
    """The largest deviation of a target rotation from orthonormality, NaN if any target is not
    finite (NaN and Inf propagate through the sums), and the deviations R^T R - I
    (`so3.gram_deviation`: its six distinct entries [B,n_o,6])."""
    R = targets.rotation
    deviation = so3.gram_deviation(R)
    largest = deviation.abs().amax() if R.shape[1] else R.new_zeros(())
    # alpha 0 keeps NaN and Inf (0 * Inf is NaN); a finite sum that overflows only takes the slow path
    values = torch.cat((targets.position, targets.linear_velocity, targets.angular_velocity), 1).sum()
    return torch.add(largest, values, alpha=0.0), deviation


def _orthonormal_tolerance(tolerance: float, dtype: torch.dtype) -> float:
    return max(tolerance, 100 * torch.finfo(dtype).eps)  # float32 rounding


def clean_steps(position, linear_velocity, rotation, angular_velocity,
                orthonormal_tolerance: float = 1e-9) -> torch.Tensor:
    """[T] bool: True at the steps whose targets `clean_targets` would leave as they are, for targets
    over time (fields as Targets with a leading T): a sequence checked at once, which its steps then
    skip (`DynamicalIK.step`'s `checked`)."""
    T = rotation.shape[0]
    if rotation.dim() != 5 or rotation.shape[-2:] != (3, 3) or any(
            x.dim() != 4 or x.shape[0] != T or x.shape[-1] != 3 or x.dtype != rotation.dtype or x.device != rotation.device
            for x in (position, linear_velocity, angular_velocity)):
        return torch.zeros(T, dtype=torch.bool)  # not targets over time: the steps check them and say why
    tolerance = _orthonormal_tolerance(orthonormal_tolerance, rotation.dtype) / 3
    # a few million entries at a time: the deviations of a large batch's part would weigh more than its rotations
    chunk = max(1, (1 << 22) // max(1, rotation[0].numel()))
    clean = []
    for start in range(0, T, chunk):
        R = rotation[start:start + chunk]
        largest = so3.gram_deviation(R).abs().flatten(1).amax(1) if R[0].numel() else R.new_zeros(len(R))
        values = torch.cat([x[start:start + chunk] for x in (position, linear_velocity, angular_velocity)], 2)
        clean.append(torch.add(largest, values.flatten(1).sum(1), alpha=0.0) <= tolerance)  # NaN, Inf: as _worst
    return torch.cat(clean) if clean else torch.zeros(0, dtype=torch.bool, device=rotation.device)


def already_clean(targets: Targets, orthonormal_tolerance: float = 1e-9) -> torch.Tensor:
    """A bool tensor: True where `clean_targets` would leave the targets as they are (every one
    finite, every rotation orthonormal to a third of orthonormal_tolerance), without a synchronisation."""
    worst, _ = _worst(targets)
    return worst <= _orthonormal_tolerance(orthonormal_tolerance, targets.rotation.dtype) / 3


_CONSTANTS: dict[tuple, torch.Tensor] = {}


def _constant(shape: tuple[int, ...], value: bool | int, device: torch.device) -> torch.Tensor:
    """A tensor of `value` (bool or long), made once per shape and device: the usual step's validity
    masks and zero counts cost no allocation. Read only, as the tracker's shared all-False tensor."""
    key = (shape, value, type(value), device)
    if key not in _CONSTANTS:
        _CONSTANTS[key] = torch.full(shape, value, dtype=torch.bool if isinstance(value, bool) else torch.long,
                                     device=device)
    return _CONSTANTS[key]


PROJECT_TOLERANCE = 1e-2  # ||R^T R - I|| (Frobenius) up to which a target rotation is projected onto SO(3)


def clean_targets(targets: Targets, project_tolerance: float = PROJECT_TOLERANCE,
                  orthonormal_tolerance: float = 1e-9, checked: bool = False) -> CleanTargets:
    """Drop non-finite targets for this step and project nearly orthonormal rotations onto SO(3).

    A rotation with `||R^T R - I|| > project_tolerance` (Frobenius) is not a rotation that noise
    or rounding could explain: InputError, naming the subject and target. checked: `clean_steps`
    found these targets clean (finite, orthonormal to a third of orthonormal_tolerance): returned as
    they are, without a check.
    """
    position, linear_velocity = targets.position, targets.linear_velocity
    rotation, angular_velocity = targets.rotation, targets.angular_velocity
    B, n_p, n_o = position.shape[0], position.shape[1], rotation.shape[1]
    if checked:
        nothing = _constant((B,), 0, position.device)
        return CleanTargets(targets, _constant((B, n_p), True, position.device),
                            _constant((B, n_o), True, position.device), nothing, nothing, True)
    eye = so3.identity(rotation.dtype, rotation.device)
    orthonormal_tolerance = _orthonormal_tolerance(orthonormal_tolerance, rotation.dtype)
    # one number for the usual case, one synchronisation
    worst_tensor, deviation = _worst(targets)
    worst = float(worst_tensor)
    all_valid = math.isfinite(worst)
    if all_valid:
        p_ok, o_ok = _constant((B, n_p), True, position.device), _constant((B, n_o), True, position.device)
    else:
        p_ok = torch.isfinite(position).all(-1) & torch.isfinite(linear_velocity).all(-1)
        o_ok = torch.isfinite(rotation).flatten(-2).all(-1) & torch.isfinite(angular_velocity).all(-1)
        position = torch.where(p_ok[..., None], position, 0.0)
        linear_velocity = torch.where(p_ok[..., None], linear_velocity, 0.0)
        rotation = torch.where(o_ok[..., None, None], rotation, eye)
        angular_velocity = torch.where(o_ok[..., None], angular_velocity, 0.0)
        all_valid = bool(p_ok.all()) and bool(o_ok.all())
        deviation = so3.gram_deviation(rotation)
        worst = float(deviation.abs().max()) if n_o else 0.0
    projected = _constant((B,), 0, position.device)
    if n_o and worst > orthonormal_tolerance / 3:
        error = so3.gram_deviation_norm(deviation)  # [B,n_o]
        far = error > project_tolerance
        if bool(far.any()):
            b, i = (int(x) for x in far.nonzero()[0])
            raise InputError(
                f"target rotation {i} of subject {b} is not a rotation (||R^T R - I|| = {float(error[b, i]):.3g} > "
                f"{project_tolerance}); give rotation matrices (link to world)"
            )
        near = error > orthonormal_tolerance
        rotation = torch.where(near[..., None, None], so3.project(rotation), rotation)
        projected = near.sum(-1)
    cleaned = Targets(position, linear_velocity, rotation, angular_velocity)
    dropped = _constant((B,), 0, position.device) if all_valid else (~p_ok).sum(-1) + (~o_ok).sum(-1)
    return CleanTargets(cleaned, p_ok, o_ok, dropped, projected, all_valid)
