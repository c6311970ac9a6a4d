"""The effects `dynamics_fit` traces the base's residual wrench to: each one's signature, its columns
in the residual's linear model r(theta) = r + G theta, and how a fitted one is added.

The residual r = (the model's base wrench without contacts) - (the plates' wrench), both about the
base's origin in world axes, [T,6]:

- a segment's mass off by dm (OpenSim's residual reduction adjusts the trunk's; the segment "body",
  every link with a mass, is the body mass stated wrong, or the plates' gain off): dm spread over the
  segment's links in proportion to their masses, at their centres of mass, inertia about the centres
  kept, adds dm G_m, G_m [T,6] the base wrench (`trajectory_dynamics`) of a model whose only masses
  are those links' shares of one kilogram, as points: the base wrench is linear in each body's mass,
  first moment and inertia;
- its centre of mass off by d along the segment (each link's centre moved along the link's axis, from
  its origin to its centre of mass): d G_c, G_c the central difference of the links' point masses'
  base wrench moved by +-EPS, exact because that wrench is quadratic in the move (a point mass's
  inertia about the link's origin) and the difference cancels the square;
- plate p's centre of pressure off by a constant d in the plate's plane (e1, e2 normal to its up):
  its moment about any point is off by d x f_p; undoing it adds (0; d x f_p), columns (0; e_i x f_p);
- the plates late by tau: read at t + tau, r(tau) = r - tau dE/dt to first order (E the plates'
  wrench about the base's origin), the column -dE/dt; the fit iterates with the plates shifted
  exactly (`shift`, a phase ramp in the frequency domain).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import torch

from ..errors import InputError
from ..method.dynamics import trajectory_dynamics
from ..method.dynamics.trajectory import Sampled
from ..method.kinematics.model import KinematicModel

EPS = 0.01  # m: the move of the centres of mass whose central difference gives G_c
# the human models' segments, by link name: the trunk is OpenSim's torso (lumbar and thoracic), not the pelvis
HUMAN_SEGMENTS = {
    "trunk": ("L5", "L3", "T12", "T8"),
    "pelvis": ("Pelvis",),
    "head": ("Neck", "Head"),
    "arms": tuple(f"{side}{part}" for side in ("Right", "Left") for part in ("Shoulder", "UpperArm", "ForeArm", "Hand")),
    "legs": tuple(f"{side}{part}" for side in ("Right", "Left") for part in ("UpperLeg", "LowerLeg", "Foot", "Toe")),
}
BODY = "body"  # the segment of every link with a mass: the body mass off as a whole


@dataclass(frozen=True)
class Effect:
    """A candidate: `kind` mass, com, cop or lag; `labels` its parameters' units; `columns` its
    columns of G [T,6,k] as a function of the plates read at the fitted lag [T,P,6] (None for the lag,
    whose column the fit takes from the plates' derivative); `segment` its links (mass, com), `plate`
    its plate (cop), `plane` the plate's two in-plane directions; `limit` the plausible size when it is
    not its kind's (`dynamics_fit.LIMITS`)."""

    name: str
    kind: str
    labels: tuple[str, ...]
    columns: Callable[[torch.Tensor], torch.Tensor] | None
    segment: tuple[str, ...] = ()
    plate: int = -1
    plane: tuple[torch.Tensor, ...] = ()
    limit: float | None = None


def segments(model: KinematicModel, given: dict[str, Sequence[str]] | None) -> dict[str, tuple[str, ...]]:
    """name -> the links of each segment that have a mass (`given`, or HUMAN_SEGMENTS on this model and
    BODY, every link with a mass)."""
    names = set(model.link_names)
    mass = _masses(model)
    out = {}
    for name, links in (HUMAN_SEGMENTS if given is None else given).items():
        unknown = [link for link in links if link not in names]
        if unknown and given is not None:
            raise InputError(f"segment {name!r}: model {model.name!r} has no link(s) {unknown}")
        massive = tuple(link for link in links if link in names and mass[link] > 0.0)
        if massive:
            out[name] = massive
    if given is None and out:
        out[BODY] = tuple(link for link in model.link_names if mass[link] > 0.0)
    if not out:
        raise InputError(f"model {model.name!r}: no segment with a mass; give segments={{name: links}}")
    return out


def segment_mass(model: KinematicModel, links: Sequence[str]) -> float:
    mass = _masses(model)
    return sum(mass[link] for link in links)


def mass_effect(model: KinematicModel, trajectory: Sampled, name: str, links: tuple[str, ...], cutoff: float,
                limit: float | None = None) -> Effect:
    """dm (kg) on the segment, G_m: the base wrench of one kilogram spread over `links` as their masses are;
    `limit` the plausible fraction of the segment's mass when not the kind's."""
    m, c = _inertial(model, links)
    G = trajectory_dynamics(_point_masses(model, links, m / m.sum(), c), trajectory, cutoff=cutoff).base_wrench
    return Effect(f"{name} mass", "mass", ("kg",), _constant(G[:, 0, :, None]), links, limit=limit)


def com_effect(model: KinematicModel, trajectory: Sampled, name: str, links: tuple[str, ...], cutoff: float) -> Effect:
    """d (m) along the segment, G_c: the base wrench's change per metre its links' centres move along their axes."""
    m, c = _inertial(model, links)
    moved = [trajectory_dynamics(_point_masses(model, links, m, c + sign * EPS * _axes(c)), trajectory,
                                 cutoff=cutoff).base_wrench[:, 0] for sign in (1.0, -1.0)]
    return Effect(f"{name} centre of mass", "com", ("m along the segment",),
                  _constant(((moved[0] - moved[1]) / (2 * EPS))[..., None]), links)


def cop_effect(plate: int, normal: torch.Tensor, name: str | None = None) -> Effect:
    """d (m, two in-plane components) of plate `plate` (from 0; `name` default "plate <plate + 1>"),
    columns (0; e_i x f_p)."""
    plane = _plane(normal)

    def columns(shifted: torch.Tensor) -> torch.Tensor:
        force = shifted[:, plate, :3]
        return torch.stack([torch.cat((torch.zeros_like(force), torch.linalg.cross(e.expand_as(force), force)), -1)
                            for e in plane], -1)

    return Effect(f"{name or f'plate {plate + 1}'} centre of pressure", "cop", ("m", "m"), columns, plate=plate,
                  plane=plane)


def lag_effect() -> Effect:
    """tau (s), the plates late by it; its column is the fit's (the plates' derivative)."""
    return Effect("plates' lag", "lag", ("s",), None)


def shift(x: torch.Tensor, rate: float, lag: float) -> torch.Tensor:
    """x [T,...] sampled at `rate` Hz read at t + lag (band-limited: a phase ramp in the frequency
    domain, the ends extended by odd reflection as `low_pass` does)."""
    T = x.shape[0]
    pad = min(T - 1, int(4 * abs(lag) * rate) + 8)
    extended = torch.cat((2 * x[:1] - x[1:pad + 1].flip(0), x, 2 * x[-1:] - x[-pad - 1:-1].flip(0)))
    n = extended.shape[0]
    f = torch.fft.rfftfreq(n, d=1.0 / rate, dtype=x.dtype)
    phase = torch.exp(2j * math.pi * f * lag).reshape(-1, *([1] * (x.dim() - 1)))
    return torch.fft.irfft(torch.fft.rfft(extended, dim=0) * phase, n=n, dim=0)[pad:pad + T]


def corrected_model(model: KinematicModel, fitted: Sequence[tuple[Effect, torch.Tensor]]) -> KinematicModel:
    """The model with the fitted masses (spread in proportion, centres and inertias about them kept)
    and centres of mass; `fitted` (effect, its values)."""
    g = model._tensors.geometry
    mass, com = g.link_mass[:, 0].clone(), g.link_com[:, :, 0].clone()
    for e, value in fitted:
        index = torch.tensor([model.link_names.index(link) for link in e.segment], dtype=torch.long)
        if e.kind == "mass":
            mass[index] *= 1.0 + float(value[0]) / float(mass[index].sum())
        elif e.kind == "com":
            com[index] += float(value[0]) * _axes(com[index])
    return model.with_inertial(mass=mass, com=com)


def corrected_plates(plates: torch.Tensor, fitted: Sequence[tuple[Effect, torch.Tensor]], rate: float,
                     lag: float) -> torch.Tensor:
    """The plates [T,P,6] with the fitted centre-of-pressure offsets undone and read at the fitted lag."""
    out = plates.clone()
    for e, value in fitted:
        if e.kind == "cop":
            d = float(value[0]) * e.plane[0] + float(value[1]) * e.plane[1]
            force = out[:, e.plate, :3]
            out[:, e.plate, 3:] -= torch.linalg.cross(d.expand_as(force), force)
    if not lag:
        return out
    unknown = out.isnan()  # a plate whose share is unknown there: shifted as zero, unknown again after
    return shift(out.nan_to_num(0.0), rate, lag).masked_fill(unknown, torch.nan)


def _masses(model: KinematicModel) -> dict[str, float]:
    return dict(zip(model.link_names, model._tensors.geometry.link_mass[:, 0].tolist()))


def _inertial(model: KinematicModel, links: Sequence[str]) -> tuple[torch.Tensor, torch.Tensor]:
    """The links' masses [L] and centres of mass [L,3] (each in its frame)."""
    index = torch.tensor([model.link_names.index(link) for link in links])
    g = model._tensors.geometry
    return g.link_mass[index, 0], g.link_com[index, :, 0]


def _point_masses(model: KinematicModel, links: Sequence[str], mass: torch.Tensor, com: torch.Tensor) -> KinematicModel:
    """The model with only `links` massive, as point masses `mass` [L] at `com` [L,3] (their frames)."""
    index = torch.tensor([model.link_names.index(link) for link in links])
    N = len(model.link_names)
    m = torch.zeros(N, dtype=model.dtype).index_copy_(0, index, mass)
    c = model._tensors.geometry.link_com[:, :, 0].clone().index_copy_(0, index, com)
    return model.with_inertial(mass=m, com=c, inertia=torch.zeros(N, 3, 3, dtype=model.dtype))


def _axes(com: torch.Tensor) -> torch.Tensor:
    """[L,3] each link's axis: from its origin to its centre of mass (z where they coincide)."""
    norm = com.norm(dim=-1, keepdim=True)
    z = torch.zeros_like(com)
    z[:, 2] = 1.0
    return torch.where(norm > 1e-9, com / norm.clamp_min(1e-9), z)


def _constant(column: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
    return lambda shifted: column


def _plane(normal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit vectors spanning the plane normal to `normal` [3]: for a level plate, the world's x and y."""
    n = normal / normal.norm()
    e1 = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0], dtype=n.dtype), n)
    if float(e1.norm()) < 1e-6:  # a wall: y is its normal
        e1 = torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0], dtype=n.dtype), n)
    e1 = e1 / e1.norm()
    return e1, torch.linalg.cross(n, e1)
