"""Ground reactions from a C3D file's force plates (FORCE_PLATFORM group, type 2).

Each plate of `FORCE_PLATFORM:USED` is read from:

- CORNERS (3,4,plate), in POINT:UNITS, the lab frame: corners 1-4 lie in the plate's quadrants
  (+x+y, -x+y, -x-y, +x-y), which gives the plate's axes in the lab (x from the -x side's midpoint
  to the +x side's, y likewise, z = x cross y: down for a plate in the floor) and its surface centre;
- ORIGIN (3,plate), in the plate frame: the transducer origin (where the moments are measured)
  against the surface centre. The C3D manual's vector points from the transducer origin to the
  surface centre, so its z is negative; Vicon (and AMTI's older sheets) store the opposite vector,
  with a positive z. As Visual3D does, a positive z is read as that opposite vector; the shared
  files store (0.33, 0.23, 40.3) mm, and read so, their moments about the surface centre equal
  Plug-in Gait's `GroundReactionMoment` to float32's rounding (4e-5 N m);
- CHANNEL (6,plate): the analog channels (from 1) of Fx, Fy, Fz, Mx, My, Mz in the plate frame,
  the moments about the transducer origin; ANALOG:UNITS says N and N mm (or N m). ezc3d has
  applied ANALOG:SCALE, GEN_SCALE and OFFSET to them already. TYPE must be 2 (the forces and
  moments themselves, as Vicon Nexus writes them); a plate of another type is skipped and named.
  CAL_MATRIX is not used (type 2 has none) and ZERO is not applied (no baseline is subtracted).

The six channels are brought to the motion's frames (`analog.to_frames`: a zero-phase low-pass,
then the sample at each frame's instant), turned into the world frame (torchik's world is the lab
frame in metres: what the C3D reader uses for the points) and made the force the plate exerts on
the body. That is how Vicon writes them; a plate whose force along its upward normal is mostly
negative where it is loaded holds the force on the plate instead, and is negated (said in
`signs`).

Below `threshold` (20 N) along the plate's upward normal the plate is unloaded: force, moment
and free moment are zero and the centre of pressure NaN. Above it, with F the force and M_c the
moment about the surface centre c, n the upward normal: the centre of pressure is
p = c + (n x M_c) / (n . F), the point of the surface about which the moment is along n, and the
free moment is n . (M_c - (p - c) x F), in N m.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from . import analog

CONTACT_THRESHOLD = 20.0  # N along the plate's upward normal: below it a plate is unloaded
MOMENT_SCALE = {"nmm": 1e-3, "n.mm": 1e-3, "n mm": 1e-3, "nm": 1.0, "n.m": 1.0, "n m": 1.0}


@dataclass(frozen=True)
class ForcePlate:
    """One plate in the world frame (m): `number` from 1 as in the file, `rotation` [3,3] plate
    frame to world, `centre` [3] of the surface, `origin` [3] the transducer origin, `corners` [4,3],
    `up` [3] the surface's upward normal, `channels` the six analog channels (from 0), `moment_scale`
    the moments' units to N m."""

    number: int
    rotation: np.ndarray
    centre: np.ndarray
    origin: np.ndarray
    corners: np.ndarray
    up: np.ndarray
    channels: tuple[int, ...]
    moment_scale: float

    def to_json(self) -> dict:
        size = np.ptp(self.rotation.T @ (self.corners - self.centre).T, axis=1)[:2]
        return dict(number=self.number, centre_m=self.centre.round(6).tolist(), size_m=size.round(6).tolist(),
                    channels=[c + 1 for c in self.channels])


@dataclass
class GroundReactions:
    """What the plates exert on the body at the motion's frames, in the world frame: `force` [T,P,3]
    N, `moment` [T,P,3] N m about the world origin, `cop` [T,P,3] m (NaN where unloaded),
    `free_moment` [T,P] N m about the upward normal at the centre of pressure, `contact` [T,P] (loaded
    above `threshold`); P plates, `skipped` those not read, with the reason; `signs` +1 per plate, -1
    where the channels held the force on the plate."""

    time: np.ndarray
    plates: tuple[ForcePlate, ...]
    force: np.ndarray
    moment: np.ndarray
    cop: np.ndarray
    free_moment: np.ndarray
    contact: np.ndarray
    threshold: float
    resampling: dict  # how the channels were brought to the frames (analog.py): method, cut-off or window, rates
    signs: tuple[int, ...] = ()
    skipped: list[str] = field(default_factory=list)

    def moment_about(self, point: np.ndarray) -> np.ndarray:
        """The moment [T,P,3] about `point` ([3] or [P,3], m, world), e.g. the plates' centres."""
        return self.moment - np.cross(np.broadcast_to(point, self.force.shape), self.force)

    def to_json(self) -> dict:
        return dict(plates=[p.to_json() for p in self.plates], threshold_n=self.threshold, resampling=self.resampling,
                    signs=list(self.signs), skipped=self.skipped)


def ground_reactions(c3d, length_scale: float, threshold: float = CONTACT_THRESHOLD,
                     method: analog.Method = "butterworth", cutoff: float | None = None) -> GroundReactions:
    """The ground reactions of an ezc3d file already read; `length_scale` turns POINT:UNITS into m.
    InputError for what cannot be read."""
    parameters = c3d["parameters"]
    frame_rate = float(np.asarray(parameters["POINT"]["RATE"]["value"]).ravel()[0])
    frames = c3d["data"]["points"].shape[2]
    plates, skipped = read_plates(parameters, length_scale)
    time = np.arange(frames) / frame_rate
    P = len(plates)
    wrench = np.zeros((frames, P, 6))
    resampling: dict = dict(method=method)
    if P:
        analog_rate = float(np.asarray(parameters["ANALOG"]["RATE"]["value"]).ravel()[0])
        samples = c3d["data"]["analogs"][0].T  # [S,C], scaled by ezc3d
        channels = [c for plate in plates for c in plate.channels]
        if max(channels) >= samples.shape[1]:
            raise InputError(f"FORCE_PLATFORM:CHANNEL names channel {max(channels) + 1}; the file has {samples.shape[1]}")
        resampled = analog.to_frames(samples[:, channels], analog_rate, frame_rate, frames, method, cutoff)
        wrench = resampled.reshape(frames, P, 6)
        resampling.update(analog_rate_hz=analog_rate, frame_rate_hz=frame_rate)
        if method == "butterworth":
            resampling.update(order=analog.ORDER, cutoff_hz=cutoff or analog.CUTOFF_FRACTION * frame_rate, zero_phase=True)
        else:
            resampling.update(window=2 * (analog.samples_per_frame(analog_rate, frame_rate) // 2) + 1)
    return plate_wrenches(plates, wrench, time, threshold, resampling, skipped)


def read_plates(parameters, length_scale: float) -> tuple[tuple[ForcePlate, ...], list[str]]:
    """The type-2 plates of FORCE_PLATFORM in the world frame (m), and a line per plate skipped."""
    group = parameters.get("FORCE_PLATFORM", {})
    used = int(np.asarray(group.get("USED", {}).get("value", [0])).ravel()[0]) if "USED" in group else 0
    if used == 0:
        return (), []
    value = lambda name: np.asarray(group[name]["value"], dtype=np.float64)  # noqa: E731
    for name in ("TYPE", "CORNERS", "ORIGIN", "CHANNEL"):
        if name not in group:
            raise InputError(f"FORCE_PLATFORM:USED is {used} but FORCE_PLATFORM:{name} is missing")
    types = value("TYPE").astype(int).ravel()
    corners = value("CORNERS").reshape(3, 4, -1)
    origins = value("ORIGIN").reshape(3, -1)
    channel = value("CHANNEL").astype(int)
    channel = channel.reshape(channel.shape[0], -1)
    units = [str(u).strip().lower() for u in parameters.get("ANALOG", {}).get("UNITS", {}).get("value", [])]
    plates, skipped = [], []
    for k in range(used):  # a few plates
        if types[k] != 2:
            skipped.append(f"plate {k + 1}: type {types[k]} is not read (only type 2, forces and moments)")
            continue
        ids = tuple(int(c) - 1 for c in channel[:6, k])
        if min(ids) < 0:
            raise InputError(f"FORCE_PLATFORM:CHANNEL of plate {k + 1} names channel {min(ids) + 1}; channels count from 1")
        moment_unit = units[ids[3]] if len(units) > max(ids) else None
        if moment_unit is not None and moment_unit not in MOMENT_SCALE:
            raise InputError(f"plate {k + 1}: moment channel {ids[3] + 1} is in {moment_unit!r}, not N mm or N m")
        if len(units) > max(ids) and any(units[i] != "n" for i in ids[:3]):
            raise InputError(f"plate {k + 1}: force channels in {[units[i] for i in ids[:3]]}, not N")
        moment_scale = MOMENT_SCALE[moment_unit] if moment_unit else length_scale  # N x POINT:UNITS when undeclared
        plates.append(_plate(k + 1, corners[:, :, k].T * length_scale, origins[:, k] * length_scale, ids, moment_scale))
    return tuple(plates), skipped


def _plate(number: int, corners: np.ndarray, origin: np.ndarray, channels: tuple[int, ...],
           moment_scale: float) -> ForcePlate:
    """A plate from its corners [4,3] (world, m) and ORIGIN [3] (plate frame, m)."""
    x = corners[[0, 3]].mean(0) - corners[[1, 2]].mean(0)  # from the -x side's midpoint to the +x side's
    y = corners[[0, 1]].mean(0) - corners[[2, 3]].mean(0)
    if np.linalg.norm(np.cross(x, y)) < 1e-9:
        raise InputError(f"FORCE_PLATFORM:CORNERS of plate {number} do not span a surface: {corners.tolist()}")
    axes = np.stack((x, y, np.cross(x, y)), axis=1)
    u, _, vt = np.linalg.svd(axes / np.linalg.norm(axes, axis=0))
    rotation = u @ vt  # the nearest rotation to the corners' axes (exact for a rectangle)
    centre = corners.mean(0)
    centre_from_origin = origin if origin[2] <= 0 else -origin  # the manual's vector (z < 0); Vicon's is its opposite
    z = rotation[:, 2]
    up = z if z[2] > 0 else -z  # torchik's world, the lab's, has z up
    return ForcePlate(number=number, rotation=rotation, centre=centre, origin=centre - rotation @ centre_from_origin,
                      corners=corners, up=up, channels=channels, moment_scale=moment_scale)


def plate_wrenches(plates: tuple[ForcePlate, ...], wrench: np.ndarray, time: np.ndarray,
                   threshold: float = CONTACT_THRESHOLD, resampling: dict | None = None,
                   skipped: list[str] | None = None) -> GroundReactions:
    """The ground reactions from each plate's channels at the frames, wrench [T,P,6] (force N and
    moment about its transducer origin, plate frame; the moments in the plate's units), as the
    module docstring says; `resampling` and `skipped` are recorded."""
    T, P = wrench.shape[:2]
    empty = lambda *shape: np.zeros((T, P, *shape))  # noqa: E731
    if P == 0:
        return GroundReactions(time, plates, empty(3), empty(3), empty(3), empty(), empty().astype(bool), threshold,
                               resampling or {}, (), skipped or [])
    R = np.stack([p.rotation for p in plates])  # [P,3,3]
    scale = np.array([p.moment_scale for p in plates])[:, None]
    force = np.einsum("pij,tpj->tpi", R, wrench[..., :3])
    at_origin = np.einsum("pij,tpj->tpi", R, wrench[..., 3:] * scale)
    origin = np.stack([p.origin for p in plates])
    centre = np.stack([p.centre for p in plates])
    up = np.stack([p.up for p in plates])
    moment = at_origin + np.cross(origin, force)  # about the world origin
    normal = (force * up).sum(-1)  # [T,P]
    signs = []
    for k in range(P):  # a plate pushes: one whose loaded samples mostly pull holds the force on the plate
        loaded = normal[:, k][np.abs(normal[:, k]) > threshold]
        signs.append(-1 if (loaded < 0).sum() > (loaded > 0).sum() else 1)
    sign = np.array(signs, dtype=np.float64)[:, None]
    force, moment, normal = force * sign, moment * sign, normal * sign[:, 0]
    finite = np.isfinite(force).all(-1) & np.isfinite(moment).all(-1)
    contact = finite & (normal > threshold)
    about_centre = moment - np.cross(centre, force)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.cross(up, about_centre) / normal[..., None]
    cop = np.where(contact[..., None], centre + d, np.nan)
    free = np.where(contact, ((about_centre - np.cross(d, force)) * up).sum(-1), 0.0)
    unloaded = finite & ~contact
    force = np.where(unloaded[..., None], 0.0, force)
    moment = np.where(unloaded[..., None], 0.0, moment)
    free = np.where(finite, free, np.nan)
    return GroundReactions(time=time, plates=plates, force=force, moment=moment, cop=cop, free_moment=free,
                           contact=contact, threshold=threshold, resampling=resampling or {}, signs=tuple(signs),
                           skipped=skipped or [])
