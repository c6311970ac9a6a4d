"""The static pose: a calibration posture that is not the one the map assumes.

A map calibrates every sensor's offset on a static frame in which the subject is taken to hold the
map's reference pose (io/maps.py, calibrate: offset = R_source^T R_reference). If the subject stood
with the links below a joint turned by P = exp(phi) from it (world frame, at the static frame: the
arms abducted or held forward instead of an N-pose's, the elbows bent), each of those links
carries the same wrong offset, seen in the frame the reference pose gives it: with K_l the link's
orientation in the reference pose (the model's frame; the subject's heading cancels),

    R_m = R C_l,   C_l = K_l^T P^T K_l,   so c_l = -K_l^T phi,   delta_l = R_hat_l c_l

and G_l = -R_hat_l K_l^T on the orientation rows of every tracked link below the joint, one phi [3]
for all of them. One candidate explains the large "misalignments" of an upper arm, forearm and hand
together, which, one link at a time, look like straps turned by 40 to 100 deg (placement.py).

Candidates: one per tracked link with tracked links below it (the posture at the joint above it),
for recordings a map calibrated on a reference pose (analysis.reference_pose).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ...io.maps import reference_configuration
from ...method import so3
from ...method.kinematics import KinematicModel
from .analysis import Analysis
from .effect import Effect, replace
from .joints import JointLimit, hinge_range, joint_groups
from .placement import UNOBSERVABLE, fit_projected

MAX_ARM = 100.0  # deg: arms held in a T-pose for an N-pose turn by 90 (an A-pose, bent elbows, by less)
MAX_POSTURE = 45.0  # deg: elsewhere (trunk, legs, head) a subject standing still is not further off
ARM_JOINTS = ("Shoulder", "Elbow")  # names of the joints above the links MAX_ARM allows for
HELD = math.radians(1.0)  # a reference pose this close to a limit holds the joint at it
POSTURE_FLOOR = 1.0  # deg: as a strap's (placement.MISALIGNMENT_FLOOR), a posture off by less changes no reported angle


def reference_rotations(model: KinematicModel, pose: str, links) -> torch.Tensor:
    """[L,3,3] the links' orientations with the model in the reference pose (base at identity)."""
    p0, R0, _ = model.zero_configuration(1)
    return model(p0, R0, reference_configuration(model, pose), list(links), jacobian=False).rotation[0].cpu()


@dataclass
class StaticPose(Effect):
    """The links params['links'] (those below the joint above `target`) calibrated in a posture turned by
    P = exp(params['rotation_vector']) (world frame at the static frame, model axes) from the map's
    reference pose params['pose']; params['reference']: each link's orientation in that pose [L,3,3]."""

    floor, unit = POSTURE_FLOOR, "deg"

    def size(self, dt):
        return self.angle()

    def offsets(self) -> np.ndarray:
        """[L,3,3] C_l = K_l^T P^T K_l: what the wrong posture leaves on each link's orientation (R_m = R C_l)."""
        K = np.asarray(self.params["reference"], dtype=np.float64)
        P = so3.exp(torch.tensor(self.params["rotation_vector"], dtype=torch.float64)).numpy()
        return K.transpose(0, 2, 1) @ P.T @ K

    def apply(self, recording, sign):
        R = recording.orientation.copy()
        for name, C in zip(self.params["links"], self.offsets()):
            i = recording.links.index(name)
            R[:, i] = R[:, i] @ (C if sign > 0 else C.transpose())
        return replace(recording, orientation=R)

    def angle(self) -> float:
        """deg: how far the posture was from the reference pose."""
        return float(np.degrees(np.linalg.norm(self.params["rotation_vector"])))

    def bound(self) -> float:
        """deg: the most a standing subject's posture below this joint can be off the reference pose."""
        return MAX_ARM if any(name in self.params["first_joint"] for name in ARM_JOINTS) else MAX_POSTURE

    def off_hinge(self) -> float:
        """deg: the part of the posture about no axis of the joint above (a knee's or an elbow's missing
        ab/adduction), which a subject cannot hold: params['joint_axes'] [k,3], the joint's axes in the world
        at the reference pose (none: every direction is the joint's)."""
        axes = np.asarray(self.params.get("joint_axes", []), dtype=np.float64).reshape(-1, 3)
        if not len(axes):
            return 0.0
        phi = np.asarray(self.params["rotation_vector"], dtype=np.float64)
        basis = np.linalg.svd(axes.T, full_matrices=False)[0]
        return float(np.degrees(np.linalg.norm(phi - basis @ (basis.T @ phi))))

    def implausible(self):
        if self.angle() > self.bound():
            return (f"a static posture {self.angle():.0f} deg from the {self.params['pose']}, beyond the {self.bound():g} "
                    f"deg a standing subject's can be: a sign of a mislabelled marker or a flipped or swapped segment frame")
        hinge = hinge_range(self.params["first_joint"]) / 2.0
        if self.off_hinge() > hinge:
            return (f"a static posture turned {self.off_hinge():.1f} deg about a direction the joint above "
                    f"{self.target} does not move (more than {hinge:g} deg): no subject stands so, and a sensor frame "
                    f"turned on {self.target} alone is what it is a sign of")
        return ""

    def refine(self, update):
        P = so3.exp(torch.tensor(update.params["rotation_vector"], dtype=torch.float64)) @ so3.exp(
            torch.tensor(self.params["rotation_vector"], dtype=torch.float64))
        self.params["rotation_vector"] = so3.log(P).tolist()
        self.stderr = update.stderr
        return self

    def summary(self):
        c = np.asarray(self.params["rotation_vector"])
        return (f"the static pose below {self.target} ({', '.join(self.params['links'])}) turned by "
                f"{self.angle():.1f} deg about ({', '.join(f'{x:+.2f}' for x in c / max(np.linalg.norm(c), 1e-12))}) "
                f"from the {self.params['pose']}")


def held_by_reference(effect: Effect, model: KinematicModel, pose: str | None) -> str:
    """Why a moved joint limit is no finding ("" when it may be one): the reference pose the sensors
    were calibrated on holds the joint at that very limit (an N-pose's shoulders), so that a subject
    who stood otherwise in the static frame shows as a motion beyond it: a sign of a static pose, not
    of a limit (a shoulder adducted through the trunk)."""
    if not isinstance(effect, JointLimit) or pose is None or effect.target not in model.joint_names:
        return ""
    held = float(reference_configuration(model, pose)[0, model.joint_names.index(effect.target)])
    if abs(held - effect.params["limit"]) > HELD:
        return ""
    return (f"the {pose} the sensors were calibrated on holds {effect.target} at this limit "
            f"({math.degrees(held):.0f} deg): a motion beyond it is a sign of a static pose that is not the {pose}")


def project_at_limits(analysis: Analysis, b: int, G: torch.Tensor) -> torch.Tensor:
    """M G for G [L,S,3,k] on each link's orientation rows -> [L,S,R,k], M the analysis' projector,
    without the joints at a limit at each sample: a posture that pushes a joint against its limit (an
    N-pose holds the shoulders at theirs) leaves its residual there."""
    M = analysis.projector(b, at_limits=True)
    columns = M[:, :, 3:].unflatten(-1, (-1, 3)).permute(0, 2, 1, 3)  # [S,L,R,3]: M's columns of each link's rows
    return (columns @ G.transpose(0, 1)).transpose(0, 1)


def fit(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, urdf: str,
        target: str | None = None) -> list[Effect]:
    """StaticPose candidates of subject b (calibrated on a map's reference pose, analysis.poses; none
    without one), one per
    tracked link with tracked links below, fitted on train and scored on test; target: only that
    link's."""
    pose = analysis.poses[b] if analysis.poses else None
    if pose is None:
        return []
    groups = [g for g in joint_groups(urdf, analysis.links) if len(g.subtree) > 1 and target in (None, g.child)]
    ok = analysis.valid[:, b]
    index = {name: i for i, name in enumerate(analysis.links)}
    groups = [g for g in groups if int((ok[:, index[g.child]] & train)[analysis.sample].sum()) >= 8
              and int((ok[:, index[g.child]] & test)[analysis.sample].sum()) >= 8]
    if not groups:
        return []
    K = reference_rotations(analysis.model, pose, analysis.links).to(analysis.R_hat.dtype)  # [L,3,3]
    G = -analysis.R_hat[analysis.sample, b].transpose(0, 1) @ K.transpose(-1, -2)[:, None]  # [L,S,3,3]
    MG_link = project_at_limits(analysis, b, G)  # [L,S,R,3]
    GG_link = G.transpose(-1, -2) @ G
    member = torch.tensor([[name in g.subtree for name in analysis.links] for g in groups], dtype=G.dtype)  # [N,L]
    MG = torch.einsum("nl,lsrk->nsrk", member, MG_link)
    GG = torch.einsum("nl,lsjk->nsjk", member, GG_link)
    top = [index[g.child] for g in groups]
    fits = fit_projected(analysis, b, MG, GG, (ok[:, top] & train[:, None]).T, (ok[:, top] & test[:, None]).T)
    out: list[Effect] = []
    for g, lf in zip(groups, fits):
        links = [name for name in analysis.links if name in g.subtree]
        params = dict(pose=pose, links=links, first_joint=g.first_joint, reference=K[[index[n] for n in links]].tolist())
        if math.isfinite(hinge_range(g.first_joint)):  # a hinge: what it cannot hold (StaticPose.off_hinge)
            params["joint_axes"] = (K[index[g.parent]] @ torch.tensor(g.axes, dtype=K.dtype).T).T.tolist()
        if not lf.identified.shape[1] or not math.isfinite(lf.fit.score):
            out.append(StaticPose("static_pose", g.child, params, notes=UNOBSERVABLE))
            continue
        out.append(StaticPose("static_pose", g.child, dict(params, rotation_vector=lf.theta.tolist()),
                              dict(rotation_vector=lf.cov.diagonal().clamp(min=0).sqrt().tolist()),
                              lf.identified.shape[1], lf.fit))
    return out
