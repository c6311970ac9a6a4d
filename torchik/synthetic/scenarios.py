"""Built-in synthetic scenarios with ground truth: t-pose, walking (4 km/h), running (10 km/h).

Joint trajectories are smooth periodic functions (a constant and two harmonics) with their exact
derivatives; amplitudes and phases follow the joint's role (hip and knee flexion, arm swing ...),
matched by name on the human models and on iCub, left and right in antiphase. The pelvis moves
forward at the gait's speed, bobbing at twice the stride frequency and swaying sideways. Targets
are what perfect sensors on every tracked link would give; `orientation_noise` (rad) and
`gyro_noise` (rad/s) add seeded sensor effects.

`ScenarioSource` makes a scenario a chunk of frames at a time, as `RecordingFile` reads a file's:
an hour's is tracked in a chunk's memory; `scenario` is its whole. Every sample is a function of
its time (the noise: of its place in the seeded stream), so chunks of any size give the same samples.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
import torch

from ..errors import InputError
from ..io.recording import Recording, per_frame_arrays
from ..method import so3
from ..method.kinematics import KinematicModel
from .motion import Motion, _rz_ry_rx, targets_from_motion


@dataclass(frozen=True)
class Gait:
    """speed (m/s), stride frequency (Hz), bob (m), sway (m), yaw (rad), and per-joint patterns:
    (name regex, offset rad, first-harmonic amplitude rad, second-harmonic amplitude rad, phase rad)."""

    speed: float
    frequency: float
    bob: float
    sway: float
    yaw: float
    patterns: tuple[tuple[str, float, float, float, float], ...]
    default_amplitude: float


_ARMS_DOWN = (
    (r"^jRightShoulder_rotx$", 1.4, 0.0, 0.0, 0.0),
    (r"^jLeftShoulder_rotx$", -1.4, 0.0, 0.0, 0.0),
    (r"^[rl]_shoulder_roll$", 0.6, 0.0, 0.0, 0.0),  # iCub: arms by the sides, inside its coupled limits
)
# The joints a gait swings, with their phase in the stride; each gait gives their amplitudes.
_SWING = (
    (r"Hip_roty$|hip_pitch$", 0.0),
    (r"Knee_roty$|knee$", -1.2),
    (r"Ankle_roty$|ankle_pitch$", -2.0),
    (r"Shoulder_roty$|shoulder_pitch$", math.pi),
    (r"Elbow_roty$|elbow$", math.pi - 0.5),
    (r"^jL5S1_rotz$|^jT9T8_rotz$|torso_yaw$", math.pi),
)


def _swinging(amplitudes) -> tuple:
    """Patterns from (first, second harmonic) amplitudes in _SWING's order, arms down."""
    return _ARMS_DOWN + tuple((regex, 0.0, h1, h2, phase) for (regex, phase), (h1, h2) in zip(_SWING, amplitudes))


SCENARIOS = {
    "tpose": Gait(0.0, 0.25, 0.003, 0.005, 0.01, ((r"^[rl]_shoulder_roll$", 1.5, 0.0, 0.0, 0.0),),
                  default_amplitude=0.01),
    "walking": Gait(4.0 / 3.6, 0.9, 0.02, 0.025, 0.05, _swinging(
        ((0.35, 0.05), (0.30, 0.25), (0.15, 0.08), (0.25, 0.02), (0.15, 0.03), (0.06, 0.0))), default_amplitude=0.03),
    "running": Gait(10.0 / 3.6, 1.4, 0.05, 0.02, 0.08, _swinging(
        ((0.55, 0.10), (0.55, 0.35), (0.25, 0.10), (0.45, 0.05), (0.25, 0.05), (0.10, 0.0))), default_amplitude=0.05),
}


def _joint_patterns(model: KinematicModel, gait: Gait, rng: np.random.Generator):
    """Per joint: offset, amplitudes of harmonics 1 and 2, phase. Left joints are half a cycle behind."""
    n = model.n_dof
    offset, a1, a2, phase = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    for j, name in enumerate(model.joint_names):
        for pattern, o, h1, h2, ph in gait.patterns:
            if re.search(pattern, name):
                offset[j] += o
                a1[j], a2[j], phase[j] = max(a1[j], h1), max(a2[j], h2), ph
        if a1[j] == 0 and a2[j] == 0:
            a1[j], phase[j] = gait.default_amplitude, rng.uniform(0, 2 * math.pi)
        if re.search(r"Left|^l_", name):
            phase[j] += math.pi
    # keep the motion inside finite limits (the clinical ranges of Human48, iCub's)
    lower, upper = model.lower.cpu().double().numpy(), model.upper.cpu().double().numpy()
    finite = (upper - lower) < 19.9
    centre = np.where(finite, np.clip(offset, lower + 0.05, upper - 0.05), offset)
    room = np.where(finite, np.minimum(centre - lower, upper - centre) - 0.02, np.inf)
    scale = np.minimum(1.0, room / np.maximum(a1 + a2, 1e-12))
    return centre, a1 * scale, a2 * scale, phase


def _within_linear_limits(model: KinematicModel, s: torch.Tensor, margin: float = 1e-3) -> bool:
    if model.linear_limits is None:
        return True
    A, b = model.linear_limits.A.cpu().double(), model.linear_limits.b.cpu().double()
    return bool((s.double() @ A.T <= b - margin).all())


# frames made at a time by `ScenarioSource.read` and in the coupled-limit check; the kinematics of a
# chunk run KINEMATICS_BATCH configurations at a time: Human66's Jacobians of its 23 tracked links
# take 80 kB a configuration (a 60 s chunk's at once: 0.5 GB)
CHUNK = 4096
KINEMATICS_BATCH = 256


@dataclass(frozen=True)
class ScenarioMotion:
    """A scenario's configuration trajectory, any of its `frames` samples at `rate` Hz made on demand
    (`motion(start, stop)`): joint patterns centre, a1, a2, phase [n] (rad), the pelvis' height (m)."""

    gait: Gait
    rate: float
    frames: int
    centre: torch.Tensor
    a1: torch.Tensor
    a2: torch.Tensor
    phase: torch.Tensor
    height: float

    def motion(self, start: int = 0, stop: int | None = None) -> Motion:
        """Samples [start, stop) with exact velocities. Motion tensors [t,1,...]."""
        gait, stop = self.gait, self.frames if stop is None else min(stop, self.frames)
        kw: dict[str, Any] = dict(dtype=torch.float64)
        t = torch.arange(start, stop, **kw) / self.rate
        w = 2 * math.pi * gait.frequency
        s, s_dot = self._joints(t)
        p = torch.stack((gait.speed * t, gait.sway * torch.sin(w * t), self.height + gait.bob * torch.sin(2 * w * t)), -1)
        p_dot = torch.stack((torch.full_like(t, gait.speed), gait.sway * w * torch.cos(w * t),
                             2 * gait.bob * w * torch.cos(2 * w * t)), -1)
        yaw, pitch = gait.yaw * torch.sin(w * t), 0.5 * gait.yaw * torch.sin(2 * w * t)
        roll = 0.5 * gait.yaw * torch.sin(w * t + 1)
        d_yaw = gait.yaw * w * torch.cos(w * t)
        d_pitch = gait.yaw * w * torch.cos(2 * w * t)
        d_roll = 0.5 * gait.yaw * w * torch.cos(w * t + 1)
        R, Rz, Ry = _rz_ry_rx(yaw, pitch, roll)
        ez = torch.tensor([0.0, 0.0, 1.0], **kw)
        omega = d_yaw[..., None] * ez + d_pitch[..., None] * Rz[..., :, 1] + d_roll[..., None] * (Rz @ Ry)[..., :, 0]
        velocity = torch.cat((p_dot, omega, s_dot), -1)
        return Motion(t, p[:, None], R[:, None], s[:, None], velocity[:, None])

    def _joints(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Joint positions and velocities [t,n] at times t [t]."""
        w = 2 * math.pi * self.gait.frequency
        arg = w * t[:, None] + self.phase
        s = self.centre + self.a1 * torch.sin(arg) + self.a2 * torch.sin(2 * arg)
        s_dot = self.a1 * w * torch.cos(arg) + 2 * self.a2 * w * torch.cos(2 * arg)
        return s, s_dot

    def within_linear_limits(self, model: KinematicModel) -> bool:
        """Whether every sample respects the model's coupled limits (checked CHUNK frames at a time)."""
        return model.linear_limits is None or all(
            _within_linear_limits(model, self._joints(torch.arange(k, min(k + CHUNK, self.frames),
                                                                   dtype=torch.float64) / self.rate)[0])
            for k in range(0, self.frames, CHUNK))


def plan_scenario(name: str, model: KinematicModel, duration: float = 10.0, rate: float = 100.0,
                        seed: int = 0) -> ScenarioMotion:
    """A scenario's configuration trajectory, its samples made when asked for (`ScenarioMotion.motion`)."""
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r}; valid: {', '.join(SCENARIOS)}")
    if duration <= 0 or rate <= 0:
        raise InputError(f"duration and rate must be positive, got {duration} s at {rate} Hz")
    gait = SCENARIOS[name]
    rng = np.random.default_rng(seed)
    centre, a1, a2, phase = (torch.from_numpy(x) for x in _joint_patterns(model, gait, rng))
    if not _within_linear_limits(model, centre[None]):
        raise InputError(f"scenario {name!r}: the neutral posture of {model.name} violates its coupled limits")
    rest = model(*model.zero_configuration(1), model.link_names, jacobian=False).position
    assert rest is not None  # forward gives positions
    motion = ScenarioMotion(gait, rate, int(round(duration * rate)) + 1, centre, a1, a2, phase,
                            float(-rest[0, :, 2].min()))
    for _ in range(19):  # shrink the swing (19 times at most) until the whole motion respects the coupled limits too
        if motion.within_linear_limits(model):
            break
        motion = dataclasses.replace(motion, a1=0.8 * motion.a1, a2=0.8 * motion.a2)
    return motion


def scenario_motion(name: str, model: KinematicModel, duration: float = 10.0, rate: float = 100.0,
                    seed: int = 0) -> Motion:
    """The configuration trajectory of a scenario, with exact velocities. Motion tensors [T,1,...]."""
    return plan_scenario(name, model, duration, rate, seed).motion()


def scenario(name: str, model: KinematicModel, links, duration: float = 10.0, rate: float = 100.0, seed: int = 0,
             orientation_noise: float = 0.0, gyro_noise: float = 0.0) -> Recording:
    """A scenario as a recording of `links` (orientation targets; the base link gives the position),
    with the true joint positions. Noise: rad (a random rotation per sample) and rad/s. The whole
    recording in memory: `ScenarioSource` makes it a chunk of frames at a time instead."""
    return ScenarioSource(name, model, links, duration, rate, seed, orientation_noise, gyro_noise).read()


class ScenarioSource:
    """A scenario made a chunk of frames at a time, as `RecordingFile` reads a file's: time [T],
    links, base_link, joint_names, meta and frames as a Recording has them, `chunks(size)` and
    `read()`. A chunk is made when asked for, so memory is a chunk's whatever the duration; the
    samples are `scenario(...)`'s however they are cut (the arguments are its)."""

    def __init__(self, name: str, model: KinematicModel, links, duration: float = 10.0, rate: float = 100.0,
                 seed: int = 0, orientation_noise: float = 0.0, gyro_noise: float = 0.0):
        self.motion = plan_scenario(name, model, duration, rate, seed)
        self.model, self.links, self.seed = model, tuple(links), seed
        self.orientation_noise, self.gyro_noise = orientation_noise, gyro_noise
        self.time = np.arange(self.motion.frames, dtype=np.float64) / rate  # as torch.arange(start, stop) / rate
        self.base_link, self.joint_names = model.base_link, model.joint_names
        self.meta = dict(source=f"torchik scenario {name}", scenario=name, model=model.name, frame_rate=rate, seed=seed,
                         orientation_noise=orientation_noise, gyro_noise=gyro_noise, speed_m_s=SCENARIOS[name].speed)

    @property
    def frames(self) -> int:
        return self.motion.frames

    def chunks(self, size: int) -> Iterator[Recording]:
        """The scenario `size` frames at a time (the last chunk shorter), each a Recording whose
        first_frame is its place in the whole."""
        if size < 1:
            raise ValueError(f"chunk size must be positive, got {size}")
        orientation_noise, gyro_noise = self._noise()
        for start in range(0, self.frames, size):
            yield self._chunk(start, min(start + size, self.frames), orientation_noise, gyro_noise)

    def read(self) -> Recording:
        """The whole scenario (made CHUNK frames at a time into its arrays)."""
        arrays: dict[str, np.ndarray] = {}
        for part in self.chunks(CHUNK):
            if len(part.time) == self.frames:
                return part
            for k, a in per_frame_arrays(part).items():
                if k not in arrays:
                    arrays[k] = np.empty((self.frames, *a.shape[1:]), a.dtype)
                arrays[k][part.first_frame:part.first_frame + len(a)] = a
        return Recording(time=self.time, links=self.links, orientation=arrays["orientation"],
                         angular_velocity=arrays["angular_velocity"], base_link=self.base_link,
                         base_position=arrays["base_position"], base_linear_velocity=arrays["base_linear_velocity"],
                         joint_names=self.joint_names, joint_positions=arrays["joint_positions"], meta=self.meta)

    def _chunk(self, start: int, stop: int, orientation_noise: _Draws | None, gyro_noise: _Draws | None) -> Recording:
        motion = self.motion.motion(start, stop)
        targets = targets_from_motion(self.model, motion, self.links, chunk=KINEMATICS_BATCH)
        R, w = targets.rotation[:, 0], targets.angular_velocity[:, 0]
        if orientation_noise is not None:
            R = so3.exp(self.orientation_noise * orientation_noise.take(R.shape[:-1])) @ R
        if gyro_noise is not None:
            w = w + self.gyro_noise * gyro_noise.take(w.shape)
        return Recording(time=self.time[start:stop], links=self.links, orientation=R.numpy(),
                         angular_velocity=w.numpy(), base_link=self.base_link,
                         base_position=targets.position[:, 0, 0].numpy(),
                         base_linear_velocity=targets.linear_velocity[:, 0, 0].numpy(), joint_names=self.joint_names,
                         joint_positions=motion.joint_positions[:, 0].numpy(), meta=self.meta, first_frame=start)

    def _noise(self) -> tuple[_Draws | None, _Draws | None]:
        """The streams of standard normal draws of the orientation and the gyro noise (None without
        it): torch.randn of [T,n,3] each, one after the other from one generator seeded seed + 1."""
        size = self.frames * len(self.links) * 3
        seeded = lambda: torch.Generator().manual_seed(self.seed + 1)  # noqa: E731
        if size < 16:  # randn draws these one by one (keeping a draw for the next): drawn whole, as it does
            g = seeded()
            orientation_draws = torch.randn(size, generator=g, dtype=torch.float64) if self.orientation_noise else None
            gyro_draws = torch.randn(size, generator=g, dtype=torch.float64) if self.gyro_noise else None
            return (None if orientation_draws is None else _Draws(iter([orientation_draws])),
                    None if gyro_draws is None else _Draws(iter([gyro_draws])))
        orientation = _Draws(_randn(seeded(), size)) if self.orientation_noise else None
        gyro = None
        if self.gyro_noise:
            g = seeded()
            if self.orientation_noise:  # past the orientation noise's draws
                _skip(g, size + (16 if size % 16 else 0))
            gyro = _Draws(_randn(g, size))
        return orientation, gyro


def _randn(generator: torch.Generator, size: int, block: int = 1 << 16) -> Iterator[torch.Tensor]:
    """torch.randn(size, dtype=torch.float64, generator=generator)'s values on the CPU (size >= 16), in
    pieces of at most `block` (a multiple of 16), drawing from the generator as randn does: `size`
    uniforms turned into normals 16 at a time (Box-Muller, the first 8 with the last 8), then, where
    `size` is not a multiple of 16, 16 more uniforms for the last 16 values. Equal to randn's to an
    ulp or two: randn takes its logarithms and sines from the C library, these from torch's
    vectorised functions."""
    main = size - 16 if size % 16 else size  # the values from the first `size` uniforms
    done = 0  # uniforms drawn
    while done < main:
        n = min(block, -(-(main - done) // 16) * 16)
        yield _box_muller(torch.rand(n, generator=generator, dtype=torch.float64))[:main - done]
        done += n
    if size % 16:
        _skip(generator, size - done)  # uniforms of values the last 16 replace
        yield _box_muller(torch.rand(16, generator=generator, dtype=torch.float64))


def _box_muller(u: torch.Tensor) -> torch.Tensor:
    """Normals from uniforms [16 k] in [0, 1), as torch's CPU normal_fill_16 makes them."""
    u = u.reshape(-1, 16)
    radius = torch.sqrt(-2 * torch.log(1 - u[:, :8]))  # 1 - u in (0, 1]
    theta = 2 * math.pi * u[:, 8:]
    return torch.cat((radius * torch.cos(theta), radius * torch.sin(theta)), 1).reshape(-1)


def _skip(generator: torch.Generator, count: int, block: int = 1 << 20) -> None:
    """The generator past `count` uniform draws."""
    for k in range(0, count, block):
        torch.rand(min(block, count - k), generator=generator, dtype=torch.float64)


class _Draws:
    """A stream of values given as pieces of a flat sequence (`_randn`'s), taken a shape at a time."""

    def __init__(self, pieces: Iterator[torch.Tensor]):
        self.pieces, self.rest = pieces, torch.empty(0, dtype=torch.float64)

    def take(self, shape) -> torch.Tensor:
        """The next prod(shape) values, shaped."""
        count = math.prod(shape)
        parts, have = [self.rest], len(self.rest)
        while have < count:
            parts.append(next(self.pieces))
            have += len(parts[-1])
        values = torch.cat(parts)
        self.rest = values[count:]
        return values[:count].reshape(shape)
