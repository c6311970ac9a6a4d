"""Plug-in Gait's own kinetics, as a Vicon C3D file holds them, beside torchik's: the comparison
`torchik dynamics` reports on such a file and `experiments/dynamics_plugin_gait.py` measures.

Plug-in Gait writes its inverse dynamics as points, per side S (L, R) and joint J (Hip, Knee, Ankle):

- `<S><J>Moment`: the internal moment per kg of PROCESSING:Bodymass, in N mm/kg (POINT:MOMENT_UNITS
  says "Nmm" and leaves the per kg unsaid), its components (x, y, z) in the distal segment's frame
  (femur, tibia, foot), x the sagittal one: about the segment's lateral axis (the Plug-in Gait
  triad's L axis, which points to the subject's left on both sides).
- `<S><J>Power`: the joint's total power in W/kg (POINT:POWER_UNITS says "W"), in the z component
  only; x and y are 0. It is the scalar product of the moment and the distal segment's angular
  velocity relative to the proximal one: fitted on the shared walks as a sum over the nine products
  of the moment's and the relative angular velocity's components in the distal frame, it is
  reproduced with r >= 0.9997 and the sagittal product M_x w_y has the coefficient +1 at the hip
  and ankle, -1 at the knee (both sides; the knee's moment is an extensor moment when positive,
  its lateral axis turns the shank the flexion's way).

Plug-in Gait's sagittal power is therefore that one term, `EXTENSOR[J] * M_x * w_y`: its extensor
moment (plantarflexor at the ankle) times the joint's extension rate about the distal segment's
lateral axis. torchik's is the joint's y degree of freedom's (the flexion axis of the human models)
torque times its rate; its total power is the sum over the joint's degrees of freedom. The
agreement is Pearson's r between the two over the frames where the foot stands on a plate
(`agreement`): elsewhere neither has the ground reaction of the foot on the floor.

Per kg of which mass: Plug-in Gait divides by PROCESSING:Bodymass (typed by the operator), torchik by
its model's mass (what the static trial's plates weigh, io/weighing.py, or Bodymass, or the loop's).
`agreement` compares the two per kg of torchik's model's mass (Plug-in Gait's values times Bodymass
over it: the same joint's power in W, then both divided by the one mass), so a mass that differs does
not show as a difference in W/kg. r does not depend on it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import optional
from ..io.c3d import _labels, read_c3d
from ..io.recording import Recording
from .dynamics import EXTENSOR, JOINTS, SIDES, MotionDynamics

SEGMENTS = {"Hip": ("PEL", "FE"), "Knee": ("FE", "TI"), "Ankle": ("TI", "FO")}  # proximal, distal (side-prefixed but PEL)
MOMENT_SCALE = 1e-3  # Plug-in Gait's N mm/kg to N m/kg


@dataclass(frozen=True)
class PlugInGaitKinetics:
    """Plug-in Gait's kinetics of one side's joint over a file's frames (NaN where it computed none):
    sagittal moment [T] (N m/kg, extensor positive), its sagittal power [T] and total power [T] (W/kg),
    per kg of `bodymass` (the file's PROCESSING:Bodymass, kg; None where it states none)."""

    moment: np.ndarray
    sagittal_power: np.ndarray
    total_power: np.ndarray
    bodymass: float | None = None

    def per_kg_of(self, mass: float) -> PlugInGaitKinetics:
        """The same kinetics per kg of `mass` (kg) instead of Bodymass (itself without a Bodymass)."""
        if not self.bodymass:
            return self
        k = self.bodymass / mass
        return PlugInGaitKinetics(self.moment * k, self.sagittal_power * k, self.total_power * k, mass)


def plug_in_gait_kinetics(path: str | Path, recording: Recording | None = None) -> dict[tuple[str, str], PlugInGaitKinetics]:
    """Plug-in Gait's kinetics in a C3D file by (side, joint), sides "Right", "Left" and joints "Hip",
    "Knee", "Ankle" (module docstring); empty when the file holds none. recording: the file read by
    `read_c3d` already (its segments' orientations and angular velocities), else it is read."""
    c3d = optional("ezc3d", "io", "reading C3D files").c3d(str(path), extract_forceplat_data=False)
    labels = _labels(c3d["parameters"]["POINT"])
    index = {label: i for i, label in enumerate(labels)}
    points = c3d["data"]["points"]  # [4,P,T]
    residual = c3d["data"]["meta_points"]["residuals"][0] if "residuals" in c3d["data"]["meta_points"] else None
    recording = recording or read_c3d(path, forces=False)
    segment = {name: i for i, name in enumerate(recording.links)}
    bodymass = (recording.meta.get("skeleton") or {}).get("mass")
    out = {}
    for side in SIDES:
        s = side[0]
        for joint in JOINTS:
            moment, power = f"{s}{joint}Moment", f"{s}{joint}Power"
            proximal, distal = (s + seg if seg != "PEL" else seg for seg in SEGMENTS[joint])
            if moment not in index or power not in index or proximal not in segment or distal not in segment:
                continue
            M = points[:3, index[moment]].T * MOMENT_SCALE  # [T,3] N m/kg, distal frame
            P = points[2, index[power]].copy()  # [T] W/kg
            computed = np.isfinite(M).all(-1) & (np.abs(M).sum(-1) > 0) & np.isfinite(P)
            if residual is not None:
                computed &= (residual[index[moment]] >= 0) & (residual[index[power]] >= 0)
            R = recording.orientation[:, segment[distal]]  # [T,3,3] distal segment to world
            w = recording.angular_velocity[:, segment[distal]] - recording.angular_velocity[:, segment[proximal]]
            extension = np.einsum("ti,ti->t", w, R[:, :, 1])  # about the distal segment's lateral axis
            sign = EXTENSOR[joint]
            out[(side, joint)] = PlugInGaitKinetics(
                moment=np.where(computed, sign * M[:, 0], np.nan),
                sagittal_power=np.where(computed, sign * M[:, 0] * extension, np.nan),
                total_power=np.where(computed, P, np.nan), bodymass=bodymass)
    return out


@dataclass(frozen=True)
class Agreement:
    """torchik's and Plug-in Gait's powers of one joint over the frames its foot stands on a plate:
    Pearson's r of the sagittal powers and of the total powers, the rms of the sagittal powers'
    difference and of Plug-in Gait's sagittal power (W/kg), and the frames compared."""

    side: str
    joint: str
    frames: int
    r_sagittal: float
    r_total: float
    rms_difference: float
    rms_plug_in_gait: float

    def to_json(self) -> dict:
        return dict(side=self.side, joint=self.joint, frames=self.frames, r_sagittal=round(self.r_sagittal, 4),
                    r_total=round(self.r_total, 4), rms_difference_w_per_kg=round(self.rms_difference, 4),
                    rms_plug_in_gait_w_per_kg=round(self.rms_plug_in_gait, 4))


def agreement(dynamics: MotionDynamics, kinetics: dict[tuple[str, str], PlugInGaitKinetics],
              min_frames: int = 10) -> list[Agreement]:
    """For each side whose foot stands on a plate for `min_frames` frames or more and each joint Plug-in
    Gait computed there: the agreement of torchik's powers with Plug-in Gait's, both per kg of the model's
    mass (module docstring)."""
    found = []
    for (side, joint), given in kinetics.items():
        pig = given.per_kg_of(dynamics.mass)
        foot = dynamics.foot(side)
        if foot is None:
            continue
        _, sagittal = dynamics.sagittal(side, joint)
        total = dynamics.total_power(side, joint)
        frames = dynamics.stance[:, dynamics.wrench_links.index(foot)] & np.isfinite(pig.sagittal_power) \
            & np.isfinite(sagittal) & np.isfinite(total)
        if frames.sum() < min_frames:
            continue
        a, b = sagittal[frames], pig.sagittal_power[frames]
        found.append(Agreement(side, joint, int(frames.sum()), _pearson(a, b),
                               _pearson(total[frames], pig.total_power[frames]),
                               float(np.sqrt(np.mean((a - b) ** 2))), float(np.sqrt(np.mean(b ** 2)))))
    return sorted(found, key=lambda a: (SIDES.index(a.side), JOINTS.index(a.joint)))


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's correlation of two series (NaN when one is constant)."""
    a, b = a - a.mean(), b - b.mean()
    scale = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / scale) if scale > 0 else float("nan")
