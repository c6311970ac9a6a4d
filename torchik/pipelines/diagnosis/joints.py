"""Effects of the model's joints: a missing degree of freedom, and limits narrower than the motion.

Both leave, on the tracked links below a joint, a rotation about one axis that the joints cannot
make: delta_j = theta(t) a for every tracked link j in the subtree, with a new angle theta(t) at
each time. With G = a on those links' rows (analysis.py), theta(t) = G^T M r / G^T M G.

- missing DoF between a tracked link c and its nearest tracked ancestor p: a is constant in p's
  frame; it is the direction maximising the explained residual sum_t (a^T s_t)^2 / a^T Q_t a, with
  s_t = R_p^T E^T M r and Q_t = R_p^T E^T M E R_p (E: identity blocks on the subtree's rows), found
  as the top generalised eigenvector of (sum s s^T, sum Q). It is scored against a constant angle
  (which is a misalignment of the sensors below): a joint must move. Added to the URDF as a
  revolute joint before the chain's first joint, so that its axis is fixed in p's frame.
- a limit too narrow: a is the joint's own axis, M is built without that joint's column (at its
  limit it cannot move), and theta > 0 beyond the limit is the range the motion needs. The limit is
  moved to the largest such excess.
"""

from __future__ import annotations

import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import torch

from ...errors import InputError
from ...method import so3
from .analysis import Analysis
from .effect import Effect, lowpass_blocks, score

REGULARISE = 0.05
MAX_WIDENING = math.radians(30.0)  # rad: people's ranges differ by 10-20 deg; a limit further off is another error
MAX_OFFSET = math.radians(30.0)  # rad: an added axis never this close to its zero, the reference pose's, sits off it
MAX_RANGE = math.pi  # rad: no joint of a body moves over more than this about one axis
# deg: the most a hinge's missing direction moves over (the angle's range), by the joint's name. The
# knee's ab/adduction spans 5 to 10 deg in gait (Kadaba et al. 1990, the Plug-in Gait normals), the
# elbow's carrying angle a few degrees as it flexes; beyond about 15 deg such an "axis" is what a frame
# turned about its segment's long axis makes of flexion (the thigh frame of a knee: flexion seen as
# ab/adduction, the cross-talk of gait labs), not a joint: a misalignment, tried as such.
HINGE_RANGE = {"Knee": 15.0, "Elbow": 15.0}


# A joint's angle in a walk or a run comes and goes with the strides; one that a straight line in time
# explains (RAMP_SHARE of its variance) over several strides (RAMP_SPAN) is a sensor's heading turning
# against its neighbour's, which a drift (drift.HeadingDrift) names with one parameter
RAMP_SHARE = 0.8
RAMP_SPAN = 5.0  # s


def hinge_range(joint: str) -> float:
    """deg: the most an axis a hinge lacks moves over at `joint` (a joint or chain name), inf elsewhere."""
    return next((bound for name, bound in HINGE_RANGE.items() if name in joint), math.inf)
ANGLE_BANDWIDTH = 4.0  # Hz: a joint's angle in walking and running; a missing axis' is fitted smoothed to it
LEVERAGE = 1e-3  # a subtree the joints follow to within this share about every axis has no axis missing
# Relevance floors (Effect.below_floor): joint angles are reported to about a degree; an axis moving by
# less than that about its mean, or a limit off by less, changes nothing a gait report shows.
AXIS_FLOOR = 1.0  # deg, the added axis' angle rms about its mean
LIMIT_FLOOR = 1.0  # deg beyond the model's limit


@dataclass(frozen=True)
class JointGroup:
    """The joints between a tracked link and its nearest tracked ancestor: child, parent, the chain's
    first joint (its parent is `parent`), the movable joints, and the tracked links below (child
    included)."""

    child: str
    parent: str
    first_joint: str
    joints: tuple[str, ...]
    subtree: tuple[str, ...]
    axes: tuple[tuple[float, float, float], ...] = ()  # the movable joints' axes in the parent's frame, at zero


def joint_groups(urdf: str, links) -> tuple[JointGroup, ...]:
    """The JointGroup of every tracked link but the root."""
    return _joint_groups(urdf, tuple(links))


@functools.lru_cache(maxsize=64)  # every round asks again for the same URDF
def _joint_groups(urdf: str, links: tuple[str, ...]) -> tuple[JointGroup, ...]:
    root = ET.fromstring(urdf)
    parent_joint = {_tag(j, "child").get("link"): j for j in root.iter("joint")}
    tracked = set(links)

    def chain(link):  # joints from the nearest tracked ancestor down to `link`
        joints, current = [], link
        while current in parent_joint:
            j = parent_joint[current]
            joints.append(j)
            current = j.find("parent").get("link")
            if current in tracked:
                return current, joints[::-1]
        return None, joints[::-1]

    def ancestors(link):
        out, current = set(), link
        while current in parent_joint:
            current = parent_joint[current].find("parent").get("link")
            out.add(current)
        return out

    groups = []
    for c in links:
        p, js = chain(c)
        movable = tuple(j.get("name") for j in js if j.get("type") != "fixed")
        if p is None or not movable:
            continue
        subtree = tuple(x for x in links if x == c or c in ancestors(x))
        axes, R = [], np.eye(3)
        for j in js:  # the chain at the zero configuration: only the origins turn the frames
            origin = j.find("origin")
            rpy = [float(x) for x in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
            R = R @ so3.rpy_to_matrix(torch.tensor(rpy, dtype=torch.float64)).numpy()
            if j.get("type") != "fixed":
                axis = j.find("axis")
                a = np.array([float(x) for x in (axis.get("xyz") if axis is not None else "1 0 0").split()])
                axes.append(tuple(R @ (a / np.linalg.norm(a))))
        groups.append(JointGroup(c, p, js[0].get("name"), movable, subtree, tuple(axes)))
    return tuple(groups)


def _tag(element: ET.Element, tag: str) -> ET.Element:
    """element's child <tag>, which a URDF joint must have."""
    found = element.find(tag)
    if found is None:
        raise InputError(f"URDF joint {element.get('name')!r} has no <{tag}>")
    return found


def _stem(group: JointGroup) -> str:
    name = group.joints[0]
    return name.rsplit("_", 1)[0] if "_rot" in name else name


@dataclass
class MissingDof(Effect):
    """A revolute axis params['axis'] [3] (unit, in the frame of `params['parent']`, orthogonal to
    the joint's own axes at zero) missing at the joint `target` (the chain from params['parent'] to
    params['child']); params['first_joint'] is the joint it is inserted before,
    params['angle_range'] the range of the fitted angle and params['angle_rms'] its rms about its mean (rad)."""

    model_effect, per_sample = True, True
    floor, unit = AXIS_FLOOR, "deg"

    def size(self, dt):
        return math.degrees(self.angle_rms())

    def angle_rms(self) -> float:
        return float(self.params.get("angle_rms", math.inf))

    def joint_name(self) -> str:
        return f"{self.target}_added"

    def augment(self, urdf: str) -> str:
        root = ET.fromstring(urdf)
        joint = next(j for j in root.iter("joint") if j.get("name") == self.params["first_joint"])
        origin = joint.find("origin")
        rpy = [float(x) for x in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
        R0 = so3.rpy_to_matrix(torch.tensor(rpy, dtype=torch.float64)).numpy()
        axis = R0.T @ np.asarray(self.params["axis"], dtype=np.float64)  # in the joint's frame
        link = f"{self.joint_name()}_link"
        new = ET.Element("joint", name=self.joint_name(), type="continuous")
        ET.SubElement(new, "parent", link=_tag(joint, "parent").get("link", ""))
        ET.SubElement(new, "child", link=link)
        if origin is not None:
            new.append(ET.fromstring(ET.tostring(origin)))
            joint.remove(origin)
        ET.SubElement(new, "axis", xyz=" ".join(f"{x:.9f}" for x in axis))
        _tag(joint, "parent").set("link", link)
        ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
        children = list(root)
        root.insert(children.index(joint), ET.Element("link", name=link))
        root.insert(children.index(joint) + 1, new)
        return ET.tostring(root, encoding="unicode")

    def implausible(self):
        lo, hi = self.params["angle_range"]
        if hi - lo > MAX_RANGE:
            return (f"an axis moving over {math.degrees(hi - lo):.0f} deg, beyond the {math.degrees(MAX_RANGE):.0f} deg "
                    f"of any joint of a body: a sign of a segment frame flipped or swapped, or of a mislabelled marker")
        if self.params.get("ramp_share", 0.0) > RAMP_SHARE and self.params.get("ramp_span", 0.0) >= RAMP_SPAN:
            return (f"an axis turning steadily one way, {math.degrees(self.params['ramp_rate']):+.2f} deg/s over "
                    f"{self.params['ramp_span']:.0f} s (a straight line in time explains "
                    f"{100 * self.params['ramp_share']:.0f} % of its angle): no joint of a body does; a sign of a heading "
                    f"drift of the {self.params['child']} or {self.params['parent']} sensor")
        hinge = hinge_range(self.target)
        if math.degrees(hi - lo) > hinge:
            return (f"an axis moving over {math.degrees(hi - lo):.0f} deg, beyond the {hinge:g} deg this hinge's missing "
                    f"direction moves over: a sign of a misplaced frame, the {self.params['parent']} frame turned about "
                    f"its long axis (which makes flexion show on this axis) or the {self.params['child']} frame turned")
        if min(abs(lo), abs(hi)) > MAX_OFFSET and lo * hi > 0:  # the calibration's static pose puts it at zero
            return (f"an axis held between {math.degrees(lo):.0f} and {math.degrees(hi):.0f} deg, never within "
                    f"{math.degrees(MAX_OFFSET):.0f} deg of the zero the static pose gives it: a sign of a static pose "
                    f"that is not the assumed one (the segment's posture in it), or of a mislabelled marker")
        return ""

    def summary(self):
        a = np.asarray(self.params["axis"])
        lo, hi = self.params["angle_range"]
        return (f"a missing axis at {self.target}: ({', '.join(f'{x:+.2f}' for x in a)}) in the {self.params['parent']} "
                f"frame, moving over [{math.degrees(lo):.1f}, {math.degrees(hi):.1f}] deg")


@dataclass
class JointLimit(Effect):
    """Joint `target`'s params['side'] limit params['limit'] (rad, the model's) is narrower than
    the motion, which needs params['needed'] (rad)."""

    model_effect, per_sample = True, True
    floor, unit = LIMIT_FLOOR, "deg"

    def size(self, dt):
        return math.degrees(self.angle_rms())

    def angle_rms(self) -> float:
        return abs(self.params["needed"] - self.params["limit"])

    def augment(self, urdf: str) -> str:
        root = ET.fromstring(urdf)
        joint = next(j for j in root.iter("joint") if j.get("name") == self.target)
        limit = _tag(joint, "limit")
        limit.set(self.params["side"], f"{self.params['needed']:.6f}")
        return ET.tostring(root, encoding="unicode")

    def refine(self, update):
        self.params["needed"] = update.params["needed"]
        self.stderr = update.stderr
        return self

    def within_error(self):
        return False  # a refit gives the range needed, not a correction of it: always taken

    def implausible(self):
        needed, limit = self.params["needed"], self.params["limit"]
        if abs(needed) > math.pi or abs(needed - limit) > MAX_WIDENING:
            return (f"a range to {math.degrees(needed):.0f} deg from a limit of {math.degrees(limit):.0f} deg: no joint "
                    f"limit is that far off (more than {math.degrees(MAX_WIDENING):.0f} deg, or beyond 180 deg): a sign of "
                    f"a static pose that is not the assumed one, or of a segment frame flipped")
        return ""

    def summary(self):
        return (f"{self.target} moves beyond its {self.params['side']} limit {math.degrees(self.params['limit']):.1f} deg, "
                f"to {math.degrees(self.params['needed']):.1f} deg")


def fit(analysis: Analysis, b: int, train: torch.Tensor, test: torch.Tensor, urdf: str,
        target: str | None = None) -> list[Effect]:
    """Missing-DoF candidates for every joint group, and limit candidates for joints at a limit
    (target: only those at that joint)."""
    return _missing(analysis, b, train, test, urdf, target) + _limits(analysis, b, train, test, target)


def _rows(analysis: Analysis, names) -> torch.Tensor:
    """E [R,3]: identity blocks on the orientation rows of the links `names`."""
    E = torch.zeros(analysis.J.shape[-2], 3, dtype=analysis.J.dtype)
    for name in names:
        E[analysis.orientation_rows(analysis.links.index(name))] = torch.eye(3, dtype=E.dtype)
    return E


def _missing(analysis, b, train, test, urdf, target=None) -> list[Effect]:
    out: list[Effect] = []
    k = analysis.sample
    tr, te = train[k], test[k]
    if int(tr.sum()) < 8 or int(te.sum()) < 8:
        return out
    groups = [g for g in joint_groups(urdf, analysis.links) if g.parent in analysis.links and target in (None, _stem(g))]
    if not groups:
        return out
    r = analysis.stacked_residual(b)
    M = analysis.projector(b)  # [S,R,R]
    Mr = (M @ r[..., None]).squeeze(-1)
    Es = [_rows(analysis, group.subtree) for group in groups]
    MEs = (M @ torch.cat(Es, dim=-1)).split(3, dim=-1)  # M E [S,R,3] of every group, in one product
    for group, E, ME in zip(groups, Es, MEs):
        E = E.expand(len(k), -1, -1)
        R_p = analysis.R_hat[k, b, analysis.links.index(group.parent)]
        Rt = R_p.transpose(-1, -2)
        s = (Rt @ (E.transpose(-1, -2) @ Mr[..., None])).squeeze(-1)  # [S,3]
        Q = Rt @ (E.transpose(-1, -2) @ ME) @ R_p  # [S,3,3]
        S_tr, Q_tr = s[tr].T @ s[tr], Q[tr].sum(0)
        if float(Q_tr.diagonal().sum()) <= LEVERAGE * 3 * int(tr.sum()) * len(group.subtree):
            continue  # the joints already turn the links below about every axis: no axis is missing
        # directions the joints nearly follow (Q small) would turn noise into large angles: keep
        # the search to those with at least REGULARISE of the mean leverage
        Q_tr = 0.5 * (Q_tr + Q_tr.T) + REGULARISE * Q_tr.diagonal().mean() * torch.eye(3, dtype=Q.dtype)
        L = torch.linalg.cholesky(Q_tr)
        Li = torch.linalg.inv(L)
        val, vec = torch.linalg.eigh(Li @ S_tr @ Li.T)
        a = Li.T @ vec[:, -1]
        a = a / a.norm()
        # rotations about the joint's own axes are what its joints already do: the axis is defined up
        # to them, and the part orthogonal to them is the one the data determine
        if group.axes:
            basis = torch.linalg.svd(torch.tensor(group.axes, dtype=a.dtype).T, full_matrices=False)[0]
            free = a - basis @ (basis.T @ a)
            if float(free.norm()) > 0.1:
                a = free / free.norm()
        a = a * (1.0 if float(a[int(a.abs().argmax())]) > 0 else -1.0)  # a line: its largest component positive
        q = (a @ Q @ a)  # [S]
        q = q.clamp(min=REGULARISE * float(q.median().clamp(min=1e-12)))
        # an angle a body moves: within ANGLE_BANDWIDTH, and so fewer values than samples to fit
        theta = lowpass_blocks((s @ a) / q, analysis.time[k], ANGLE_BANDWIDTH, tr, te)
        pred = (ME @ (R_p @ a)[..., None]).squeeze(-1) * theta[:, None]  # [S,R]
        rows = E[0].abs().sum(-1) > 0
        # a constant angle is a sensor misalignment: a DoF must explain the residual's variation in time
        mean = float((s[tr] @ a).sum() / q[tr].sum())
        steady = (ME @ (R_p @ a)[..., None]).squeeze(-1) * mean
        span = int(te.sum()) * float(torch.diff(analysis.time[k]).median())
        fit = score((r - steady)[te][:, rows], (r - pred)[te][:, rows], 2, per_sample=int(te.sum()),
                    free=2.0 * ANGLE_BANDWIDTH * span)
        # the axis' uncertainty: explained variance along it against the next direction, in noise units
        gap = float(val[-1] - val[-2]) if len(val) > 1 else float(val[-1])
        sd = math.sqrt(fit.sigma2 * fit.tau / max(gap, 1e-30))
        both = tr | te
        out.append(MissingDof("missing_dof", _stem(group), dict(
            axis=a.tolist(), parent=group.parent, child=group.child, first_joint=group.first_joint,
            angle_range=[float(theta[both].min()), float(theta[both].max())],
            angle_rms=float(theta[both].std()), angle_mean=float(theta[both].mean()),
            **_ramp(analysis.time[k][both], theta[both])),
            dict(axis_rad=sd), 2, fit))
    return out


def _ramp(time: torch.Tensor, angle: torch.Tensor) -> dict:
    """The straight line through an added axis' angle [n] at times [n]: its slope (rad/s), the share of the
    angle's variance it explains, and the span of time it covers (s)."""
    t = time - time.mean()
    slope = float((t * (angle - angle.mean())).sum() / t.square().sum().clamp(min=1e-300))
    share = slope ** 2 * float(t.square().sum()) / max(float((angle - angle.mean()).square().sum()), 1e-300)
    return dict(ramp_rate=slope, ramp_share=min(share, 1.0), ramp_span=float(time[-1] - time[0]) if len(time) else 0.0)


def _limits(analysis, b, train, test, target=None) -> list[Effect]:
    out: list[Effect] = []
    model, k = analysis.model, analysis.sample
    active = analysis.active[k, b]  # [S,n]
    if not bool(active.any()):
        return out
    r = analysis.stacked_residual(b)
    mask = analysis.model.select(analysis.links).ancestor_mask  # [L,n]
    for j in torch.nonzero(active.any(0)).flatten().tolist():
        if target not in (None, model.joint_names[j]):
            continue
        at = active[:, j]
        s_j = analysis.s[k, b, j]
        upper = bool((s_j[at] > 0.5 * (model.lower[j] + model.upper[j])).double().mean() > 0.5)
        limit = float(model.upper[j] if upper else model.lower[j])
        below = [name for name, m in zip(analysis.links, mask[:, j].tolist()) if m]
        if not below:
            continue
        E = _rows(analysis, below)
        G = E @ analysis.joint_axes[:, b, j][..., None]  # [S,R,1]
        # M without the joint's column at the samples where it is at its limit (it cannot move); only
        # those samples are fitted, the others' M G is multiplied by zero
        MG = torch.zeros_like(G)
        held = (torch.arange(model.n_dof) == j).expand(int(at.sum()), -1)  # [P,n]: the joint, at each such sample
        MG[at] = analysis.project(b, G[at], *analysis.without(b, held, at), at)
        q = (MG.transpose(-1, -2) @ MG).flatten()
        at = at & (q > REGULARISE * float(q[at].median())) if bool(at.any()) else at
        theta = (MG.transpose(-1, -2) @ r[..., None]).flatten() / q.clamp(min=1e-12)
        sign = 1.0 if upper else -1.0
        # the angle needed beyond the limit, smoothed over a few samples so that the largest is not a noise peak
        excess = torch.where(at, (sign * theta).clamp(min=0.0), 0.0)
        smooth = torch.nn.functional.avg_pool1d(excess[None, None], 5, 1, 2, count_include_pad=False)[0, 0]
        excess = torch.where(at, smooth, 0.0)
        tr, te = at & train[k], at & test[k]
        if int(tr.sum()) < 3 or int(te.sum()) < 3:
            continue
        reach = float(excess[tr].max())
        if reach > math.pi:  # nothing a joint limit explains
            continue
        pred = MG[..., 0] * (sign * excess.clamp(max=reach))[:, None]
        rows = E.abs().sum(-1) > 0
        fit = score(r[te][:, rows], (r - pred)[te][:, rows], 1, per_sample=int(te.sum()))
        needed = limit + sign * float(excess.max())
        sd = math.sqrt(fit.sigma2 * fit.tau / float((MG[at] ** 2).sum(1).mean().clamp(min=1e-12)))
        out.append(JointLimit("joint_limit", model.joint_names[j], dict(
            side="upper" if upper else "lower", limit=limit, needed=needed), dict(needed=sd), 1, fit))
    return out
