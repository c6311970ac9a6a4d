"""The diagnosis tried on recordings it shares no assumption with, scored against what was injected.

    python experiments/diagnosis_study.py [--seeds 10] [--pairs 10] [--clean 20] [--duration 12]
                                          [--families F1,F2] [--json FILE] [--markdown FILE] [--recordings DIR]

Recordings come from the published Human48 (and, for a missing axis, Human66) URDF in
../shared/reference-models, through pinocchio's kinematics (not torchik's): a moving base (a walk
with turns, sway, roll and pitch) and every joint a sum of three sinusoids of random frequency
(0.1 to 1.2 Hz), phase and amplitude within its limits, nothing like the tracker's scenarios. Each
link's orientation and world angular velocity are pinocchio's; delays are the motion evaluated at
t - d (exact, not interpolated). Noise: white, AR(1) (phi 0.8 to 0.98) or 1/f, on orientations
(0.3 to 1 deg rms) and gyros (0.005 to 0.02 rad/s rms), the model and levels drawn per recording.

Each recording carries one effect of a family (FAMILIES, on random links with random sizes over
the ranges below), two effects of different families, or none. `torchik.diagnose` (the library
API, Human48 as `torchik diagnose --model human48` builds it) runs on each; scored: every injected
effect named on its links, spurious effects kept, nothing on clean ones, and the MNTE after against
tracking the same recording without the effect (same motion and noise).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference-models" / "humanSubject01_{dof}dof.urdf"
FAMILIES = ("misalignment", "gyro_bias", "stream_delay", "heading_drift", "missing_axis", "sensor_delay")
OPTIONAL = ("gyro_scale",)
NOISES = ("white", "ar1", "pink")
# axes Human66 has and Human48 lacks, that a body makes: knee ab/adduction, elbow and wrist, head and spine rotation
MISSING_AXES = ("jRightKnee_rotx", "jLeftKnee_rotx", "jRightElbow_rotx", "jLeftElbow_rotx", "jC1Head_rotz",
                "jRightWrist_roty", "jLeftWrist_roty", "jL5S1_rotz")
DEG = math.pi / 180


@dataclass
class Injected:
    """One injected effect: family, the links (or the joint) it is on, its size per target (family's unit)."""

    family: str
    targets: list[str]
    sizes: list[float]
    unit: str
    extra: dict = field(default_factory=dict)

    def kinds(self) -> tuple[str, ...]:
        """The diagnosis' effect kinds that name it."""
        return {"missing_axis": ("missing_dof",)}.get(self.family, (self.family,))


# ------------------------------------------------------------------------------ motion (pinocchio)
class Body:
    """A pinocchio model (free-flyer base) of a reference URDF and a random smooth motion of its joints."""

    def __init__(self, dof: int, links, rng: np.random.Generator, moving: list[str], duration: float):
        import pinocchio

        self.pin = pinocchio
        self.model = pinocchio.buildModelFromUrdf(str(REFERENCE).format(dof=dof), pinocchio.JointModelFreeFlyer())
        self.data = self.model.createData()
        self.frames = [self.model.getFrameId(name) for name in links]
        self.index = [self.model.joints[self.model.getJointId(n)].idx_q for n in moving]
        self.vindex = [self.model.joints[self.model.getJointId(n)].idx_v for n in moving]
        # the limits of Human48, the diagnosed model (Human66's are +-10 rad: none)
        limits = pinocchio.buildModelFromUrdf(str(REFERENCE).format(dof=48))
        lo = np.array([limits.lowerPositionLimit[limits.joints[limits.getJointId(n)].idx_q] for n in moving])
        hi = np.array([limits.upperPositionLimit[limits.joints[limits.getJointId(n)].idx_q] for n in moving])
        # a posture about the T-pose (zero), swinging by at most 0.6 rad, within the limits: far from
        # zero, a shoulder with a 3-rad range puts the tracker's start on another branch of its IK
        half = np.minimum(0.5 * (hi - lo) - 0.05, 0.6)
        amplitude = half * rng.uniform(0.3, 1.0, len(moving))
        self.centre = np.clip(rng.uniform(-0.25, 0.25, len(moving)), lo + 0.05 + amplitude, hi - 0.05 - amplitude)
        self.amp = amplitude[:, None] * rng.dirichlet(np.ones(3), len(moving))  # [n,3]: sums to the amplitude
        self.freq = 2 * math.pi * rng.uniform(0.1, 1.2, (len(moving), 3))
        self.phase = rng.uniform(0, 2 * math.pi, (len(moving), 3))
        # base: a walk at 0.5-1.2 m/s that turns, sways and bobs; roll and pitch of a few degrees
        self.speed = rng.uniform(0.5, 1.2)
        self.turn = (rng.uniform(0.1, 0.5), 2 * math.pi * rng.uniform(0.03, 0.1), rng.uniform(0, 2 * math.pi))
        self.sway = [(rng.uniform(0.01, 0.04), 2 * math.pi * rng.uniform(0.8, 1.2), rng.uniform(0, 2 * math.pi))
                     for _ in range(5)]  # lateral, vertical, roll, pitch, yaw wobble
        self.heading0 = rng.uniform(-math.pi, math.pi)
        self.duration = duration

    def joints(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        arg = self.freq * t + self.phase
        return self.centre + (self.amp * np.sin(arg)).sum(1), (self.amp * self.freq * np.cos(arg)).sum(1)

    def base(self, t: float):
        """Base position, rotation, and world linear and angular velocity at t."""
        a, w, ph = self.turn
        heading = self.heading0 + a / w * (math.sin(w * t + ph) - math.sin(ph))
        heading_rate = a * math.cos(w * t + ph)
        wob = [(A * math.sin(f * t + p), A * f * math.cos(f * t + p)) for A, f, p in self.sway]
        (lat, dlat), (up, dup), (roll, droll), (pitch, dpitch), (yaw, dyaw) = wob
        yaw, dyaw = heading + 3 * yaw, heading_rate + 3 * dyaw
        forward = np.array([math.cos(heading), math.sin(heading), 0.0])
        left = np.array([-math.sin(heading), math.cos(heading), 0.0])
        p = self._path(t) + lat * left + np.array([0, 0, 0.95 + up])
        v = self.speed * forward + dlat * left - lat * heading_rate * forward + np.array([0, 0, dup])
        Rz, Ry, Rx = (self.pin.rpy.rpyToMatrix(0, 0, yaw), self.pin.rpy.rpyToMatrix(0, 3 * pitch, 0),
                      self.pin.rpy.rpyToMatrix(3 * roll, 0, 0))
        ex, ey, ez = np.eye(3)
        omega = dyaw * ez + Rz @ (3 * dpitch * ey + Ry @ (3 * droll * ex))
        return p, Rz @ Ry @ Rx, v, omega

    def _path(self, t: float, steps: int = 200) -> np.ndarray:
        """The integral of speed * forward(heading(s)) over [0, t] (trapezoid on a fine grid)."""
        s = np.linspace(0.0, t, steps)
        a, w, ph = self.turn
        heading = self.heading0 + a / w * (np.sin(w * s + ph) - math.sin(ph))
        f = self.speed * np.stack((np.cos(heading), np.sin(heading)), -1)
        xy = np.trapezoid(f, s, axis=0) if t > 0 else np.zeros(2)
        return np.array([xy[0], xy[1], 0.0])

    def sample(self, t: float, extra: dict | None = None):
        """Link rotations [L,3,3] and world angular velocities [L,3], base position and velocity at t;
        extra: {joint: (amplitude, freq, phase)} moved on top (a joint the diagnosed model lacks)."""
        pin = self.pin
        p, R, v, omega = self.base(t)
        s, ds = self.joints(t)
        q, dq = pin.neutral(self.model), np.zeros(self.model.nv)
        q[:3], q[3:7] = p, pin.Quaternion(R).coeffs()
        dq[:3], dq[3:6] = R.T @ v, R.T @ omega
        q[self.index], dq[self.vindex] = s, ds
        for name, (A, f, ph) in (extra or {}).items():
            j = self.model.joints[self.model.getJointId(name)]
            q[j.idx_q], dq[j.idx_v] = A * math.sin(f * t + ph), A * f * math.cos(f * t + ph)
        pin.forwardKinematics(self.model, self.data, q, dq)
        pin.updateFramePlacements(self.model, self.data)
        frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        rot = np.stack([self.data.oMf[f].rotation for f in self.frames])
        w = np.stack([pin.getFrameVelocity(self.model, self.data, f, frame).angular for f in self.frames])
        return rot, w, p, v

    def series(self, time_: np.ndarray, extra: dict | None = None):
        out = [self.sample(float(t), extra) for t in time_]
        return tuple(np.stack(x) for x in zip(*out))


# ------------------------------------------------------------------------------ noise and effects
def coloured(kind: str, shape: tuple, rng: np.random.Generator, phi: float) -> np.ndarray:
    """Unit-variance noise along axis 0: white, AR(1) with coefficient phi, or 1/f (pink)."""
    e = rng.standard_normal(shape)
    if kind == "white":
        return e
    if kind == "ar1":
        x = np.empty(shape)
        x[0] = e[0]
        for k in range(1, shape[0]):
            x[k] = phi * x[k - 1] + math.sqrt(1 - phi ** 2) * e[k]
        return x
    spectrum = np.fft.rfft(e, axis=0)
    f = np.fft.rfftfreq(shape[0])
    f[0] = f[1]
    x = np.fft.irfft(spectrum / np.sqrt(f).reshape(-1, *([1] * (len(shape) - 1))), n=shape[0], axis=0)
    return (x - x.mean(0)) / x.std(0)


def expm(vectors: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors [...,3] -> [...,3,3]."""
    import pinocchio

    flat = vectors.reshape(-1, 3)
    return np.stack([pinocchio.exp3(v) for v in flat]).reshape(*vectors.shape[:-1], 3, 3)


def unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def draw(family: str, links, rng: np.random.Generator, moving: list[str]) -> Injected:
    """A random instance of a family: links, sizes (misalignment 5-30 deg, bias 0.5-3 deg/s, stream
    delay 20-100 ms, drift 0.5-3 deg/s, missing axis swinging 5-15 deg, sensor delay 30-100 ms)."""
    some = lambda k: [str(x) for x in rng.choice(links, k, replace=False)]  # noqa: E731
    k = int(rng.integers(1, 5))
    if family == "misalignment":
        return Injected(family, some(k), list(rng.uniform(5, 30, k)), "deg", dict(axes=[unit(rng) for _ in range(k)]))
    if family == "gyro_bias":
        return Injected(family, some(k), list(rng.uniform(0.5, 3, k)), "deg/s", dict(axes=[unit(rng) for _ in range(k)]))
    if family == "gyro_scale":
        return Injected(family, some(k), list(rng.choice([-1, 1], k) * rng.uniform(2, 8, k)), "%")
    if family == "stream_delay":
        return Injected(family, ["all"], [float(rng.uniform(20, 100))], "ms")
    if family == "heading_drift":
        return Injected(family, some(k), list(rng.choice([-1, 1], k) * rng.uniform(0.5, 3, k)), "deg/s")
    if family == "sensor_delay":
        return Injected(family, some(1), [float(rng.uniform(30, 100))], "ms")
    if family == "missing_axis":
        joint = str(rng.choice(MISSING_AXES))
        amp = float(rng.uniform(5, 15))
        return Injected(family, [joint.rsplit("_", 1)[0]], [amp], "deg", dict(
            joint=joint, motion=(amp * DEG, 2 * math.pi * float(rng.uniform(0.2, 1.0)), float(rng.uniform(0, 6.3)))))
    raise ValueError(family)


@dataclass
class Case:
    """One recording of the study: its seed, the families injected (none: clean) and the noise model."""

    seed: int
    families: tuple[str, ...]
    noise: str

    @property
    def group(self) -> str:
        return {0: "clean", 1: self.families[0] if self.families else ""}.get(len(self.families), "two effects")


def generate(case: Case, links, duration: float, rate: float):
    """(recording with the effects, the same without them, the Injected list, noise levels)."""
    from torchik.io.recording import Recording

    rng = np.random.default_rng(case.seed)
    import pinocchio

    m48 = pinocchio.buildModelFromUrdf(str(REFERENCE).format(dof=48), pinocchio.JointModelFreeFlyer())
    moving = [m48.names[j] for j in range(2, m48.njoints)]
    dof = 66 if "missing_axis" in case.families else 48
    body = Body(dof, links, rng, moving, duration)
    injected = [draw(f, links, rng, moving) for f in case.families]
    extra = {i.extra["joint"]: i.extra["motion"] for i in injected if i.family == "missing_axis"}
    t = np.arange(0.0, duration, 1.0 / rate)
    R, w, p, v = body.series(t, extra)
    R0, w0 = (body.series(t)[:2]) if extra else (R.copy(), w.copy())
    R, w = R.copy(), w.copy()
    for inj in injected:  # the streams' timing first: they are the motion at another time
        if inj.family == "stream_delay":
            w = body.series(t - inj.sizes[0] * 1e-3, extra)[1]
        if inj.family == "sensor_delay":
            i = links.index(inj.targets[0])
            late = body.series(t - inj.sizes[0] * 1e-3, extra)
            R[:, i], w[:, i] = late[0][:, i], late[1][:, i]
    for inj in injected:
        for n, (link, size) in enumerate(zip(inj.targets, inj.sizes)):
            i = links.index(link) if link in links else -1
            if inj.family == "misalignment":
                R[:, i] = R[:, i] @ expm(inj.extra["axes"][n] * size * DEG)
            elif inj.family == "heading_drift":
                Rz = expm(np.outer(size * DEG * (t - t[0]), [0.0, 0.0, 1.0]))
                R[:, i], w[:, i] = Rz @ R[:, i], (Rz @ w[:, i, :, None])[..., 0]
    for inj in injected:  # a gyro's own errors, in the frame of the sensor as it sits
        for n, (link, size) in enumerate(zip(inj.targets, inj.sizes)):
            i = links.index(link) if link in links else -1
            if inj.family == "gyro_bias":
                w[:, i] += R[:, i] @ (inj.extra["axes"][n] * size * DEG)
            elif inj.family == "gyro_scale":
                w[:, i] *= 1.0 + size / 100
    sigma_o, sigma_g = float(rng.uniform(0.3, 1.0)), float(rng.uniform(0.005, 0.02))
    phi = float(rng.uniform(0.8, 0.98))
    noise_o = expm(sigma_o * DEG * coloured(case.noise, (len(t), len(links), 3), rng, phi))
    noise_g = sigma_g * coloured(case.noise, (len(t), len(links), 3), rng, phi)
    make = lambda R_, w_: Recording(time=t, links=tuple(links), orientation=noise_o @ R_, angular_velocity=w_ + noise_g,  # noqa: E731
                                    base_link="Pelvis", base_position=p, base_linear_velocity=v)
    return make(R, w), make(R0, w0), injected, dict(noise=case.noise, orientation_deg=sigma_o, gyro_rad_s=sigma_g,
                                                    phi=phi if case.noise == "ar1" else None)


# ------------------------------------------------------------------------------ scoring
SIZE = {"misalignment": lambda p: np.degrees(np.linalg.norm(p["rotation_vector"])),
        "gyro_bias": lambda p: np.degrees(np.linalg.norm(p["bias"])), "gyro_scale": lambda p: 100 * p["scale_error"],
        "stream_delay": lambda p: 1e3 * p["delay"], "sensor_delay": lambda p: 1e3 * p["delay"],
        "heading_drift": lambda p: np.degrees(p["rate"]),
        "missing_dof": lambda p: np.degrees(0.5 * (p["angle_range"][1] - p["angle_range"][0]))}


def judge(injected: list[Injected], effects) -> dict:
    """Which injected effects were named on their links, which kept effects name none (spurious)."""
    matched, named, sizes = set(), [], []
    for inj in injected:
        found_all = True
        for target, size in zip(inj.targets, inj.sizes):
            hit = [k for k, e in enumerate(effects) if e.kind in inj.kinds() and e.target == target]
            found_all &= bool(hit)
            matched.update(hit)
            sizes += [dict(family=inj.family, target=target, injected=float(size),
                           found=float(SIZE[effects[k].kind](effects[k].params))) for k in hit[:1]]
        # a device's delay found on single gyros: the right cause, not spurious, not named as one
        matched.update(k for k, e in enumerate(effects) if inj.family == "stream_delay" and e.kind == "stream_delay")
        named.append(found_all)
    spurious = [f"{e.kind} at {e.target}" for k, e in enumerate(effects) if k not in matched]
    return dict(named=all(named), spurious=spurious, sizes=sizes)


def run_case(case: Case, model, urdf: str, links, args) -> dict:
    from torchik import diagnose
    from torchik.pipelines.diagnosis.analysis import analyse
    from torchik.pipelines.diagnosis.loop import errors

    recording, clean, injected, noise = generate(case, links, args.duration, args.rate)
    start = time.perf_counter()
    d = diagnose(model, urdf, [recording], links, max_effects=args.max_effects)[0]
    seconds = time.perf_counter() - start
    reference = errors(analyse(model, [clean], links), 0).overall["mnte"]
    verdict = judge(injected, d.effects)
    return dict(seed=case.seed, group=case.group, families=list(case.families), noise=noise, seconds=seconds,
                injected=[dict(family=i.family, targets=i.targets, sizes=[float(x) for x in i.sizes], unit=i.unit)
                          for i in injected],
                kept=[e.summary() for e in d.effects], rejected=[f"{e.kind} at {e.target}: {e.notes}" for e in d.rejected],
                complete=d.complete, stop=d.stop, noise_share=d.noise.share if d.noise else None,
                mnte_before=d.before.overall["mnte"], mnte_after=d.after.overall["mnte"], mnte_clean=reference, **verdict)


def cases(args) -> list[Case]:
    rng = np.random.default_rng(args.seed)
    out = [Case(args.seed * 10000 + 100 * f + s, (family,), NOISES[(f + s) % len(NOISES)])
           for f, family in enumerate(args.families) for s in range(args.seeds)]
    for k in range(args.pairs):
        pair = tuple(str(x) for x in rng.choice(args.families, 2, replace=False))
        out.append(Case(args.seed * 10000 + 5000 + k, pair, NOISES[k % len(NOISES)]))
    out += [Case(args.seed * 10000 + 7000 + k, (), NOISES[k % len(NOISES)]) for k in range(args.clean)]
    return out


# ------------------------------------------------------------------------------ table
def table(results: list[dict]) -> str:
    groups: dict[str, list[dict]] = {}
    for r in results:
        groups.setdefault(r["group"], []).append(r)
    lines = ["| recordings | n | injected named on their links | nothing spurious kept | spurious kept, per recording "
             "| MNTE after / clean (median, max) | time (s, median, max) |", "|---|---|---|---|---|---|---|"]
    for name, rows in groups.items():
        ratio = [r["mnte_after"] / max(r["mnte_clean"], 1e-30) for r in rows]
        named = "-" if name == "clean" else f"{sum(r['named'] for r in rows)} of {len(rows)}"
        seconds = [r["seconds"] for r in rows]
        lines.append(f"| {name} | {len(rows)} | {named} | {sum(not r['spurious'] for r in rows)} of {len(rows)} | "
                     f"{', '.join(str(len(r['spurious'])) for r in rows)} | {np.median(ratio):.2f}, {max(ratio):.2f} | "
                     f"{np.median(seconds):.0f}, {max(seconds):.0f} |")
    effect = [r for r in results if r["group"] != "clean"]
    clean = [r for r in results if r["group"] == "clean"]
    ratio = [r["mnte_after"] / max(r["mnte_clean"], 1e-30) for r in results]
    lines += ["", f"Injected effects all named on their links: {sum(r['named'] for r in effect)} of {len(effect)}; "
              f"nothing spurious kept: {sum(not r['spurious'] for r in effect)} of {len(effect)}; "
              f"nothing kept on clean recordings: {sum(not r['spurious'] for r in clean)} of {len(clean)}; "
              f"MNTE after within 1.5x of the clean recording's: {sum(x <= 1.5 for x in ratio)} of {len(ratio)}."]
    return "\n".join(lines)


_WORKER: dict = {}


def _start_worker(args) -> None:
    """A study process: one torch thread, the diagnosed model loaded once."""
    from torchik.method.models import TRACKED_LINKS, human_urdf, load_model

    torch.set_num_threads(1)
    _WORKER.update(args=args, urdf=human_urdf(48), model=load_model("human48"), links=list(TRACKED_LINKS["human48"]))


def _diagnosed(case: Case) -> dict:
    w = _WORKER
    return run_case(case, w["model"], w["urdf"], w["links"], w["args"])


@contextlib.contextmanager
def _pool(args):
    """An object with imap: --jobs processes (spawned: torch's threads do not survive a fork), or this one."""
    if args.jobs <= 1:
        _start_worker(args)
        yield SimpleNamespace(imap=map)
        return
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(args.jobs, _start_worker, (args,)) as pool:
        yield pool


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="recordings per family (default 10)")
    parser.add_argument("--pairs", type=int, default=10, help="recordings with two effects of different families")
    parser.add_argument("--clean", type=int, default=20, help="recordings with no effect")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds per recording (default 12)")
    parser.add_argument("--rate", type=float, default=50.0, help="frames per second (default 50)")
    parser.add_argument("--families", type=lambda s: tuple(s.split(",")), default=FAMILIES,
                        help=f"comma-separated, of {', '.join(FAMILIES + OPTIONAL)} (default the first six)")
    parser.add_argument("--max-effects", type=int, default=8, help="the loop's rounds (default 8, as torchik diagnose)")
    parser.add_argument("--seed", type=int, default=1, help="the study's seed (default 1)")
    parser.add_argument("--jobs", type=int, default=1, help="recordings diagnosed at once, each in its own process on "
                                                           "one thread (default 1)")
    parser.add_argument("--json", metavar="FILE", help="write every recording's result here")
    parser.add_argument("--markdown", metavar="FILE", help="write the table here")
    parser.add_argument("--recordings", metavar="DIR", help="only write each recording to DIR/GROUP_SEED.npz (to time "
                                                            "`torchik diagnose` on them), diagnose none")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    from torchik.method.models import TRACKED_LINKS

    links = list(TRACKED_LINKS["human48"])
    if args.recordings:
        from torchik.io.recording import save_recording

        Path(args.recordings).mkdir(parents=True, exist_ok=True)
        for case in cases(args):
            path = Path(args.recordings) / f"{case.group.replace(' ', '_')}_{case.seed}.npz"
            print(save_recording(generate(case, links, args.duration, args.rate)[0], path))
        return 0
    results = []
    with _pool(args) as pool:
        for case, r in zip(cases(args), pool.imap(_diagnosed, cases(args))):
            results.append(r)
            print(f"{case.group:>14} seed {case.seed} {case.noise:>5}: {'named' if r['named'] else 'MISSED'}, "
                  f"spurious {r['spurious']}, MNTE {r['mnte_after']:.3g} (clean {r['mnte_clean']:.3g}), "
                  f"{r['seconds']:.0f} s", file=sys.stderr, flush=True)
    text = table(results)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float) + "\n")
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
