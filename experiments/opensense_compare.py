"""torchik and OpenSense (OpenSim's IMU pipeline) on the same OpenSense-format recording of a
simulated walk, both against the truth: joint-angle accuracy and frames per second, in one run.

    PYTHONPATH=. python experiments/opensense_compare.py --out opensense_run/ [--seed 0] [--gain K] [--no-opensim]

1. The recording. Human48 (the URDF torchik ships, through pinocchio: sensor_physics.Body) stands
   still in the N-pose for STILL seconds, eases into a walk over RAMP seconds and walks (sensor_physics'
   walking_motion: gait curves on the hips, knees and ankles, pelvis and trunk motion, a few degrees
   on every other joint). Eight IMUs are strapped on as OpenSense's users place them (pelvis on the
   sacrum, its z axis backwards; torso on the sternum; thighs and shanks laterally and on the tibia;
   feet on the instep), each turned from its nominal placement by a strap error of 3-8 deg, 3-8 cm
   off the segment's origin; each is simulated as sensor_physics does (gyro, accelerometer,
   magnetometer with noise; Mahony's 9-axis filter at 400 Hz) and reports at 100 Hz. They are
   written as OpenSense writes them: `walk_orientations.sto` (quaternions, IMU to a z-up world) and
   `walk_angular_velocity.sto` (gyro rates, IMU axes).
2. torchik: `torchik track --input walk_orientations.sto --model human48 --out torchik.mot --out
   torchik_orientationErrors.sto`: no map given (auto: opensense_to_human, offsets calibrated on
   the first frame, heading from pelvis_imu's -z), the base held (an IMU set measures no position).
3. OpenSense: the same kinematic chains in an OpenSim model (built here from the same URDF: pelvis
   free, L5-L3-T12-T8 trunk, hips 3, knees 2, ankles 3 rotations as Human48's joints, its
   coordinates named as Human48's; OpenSim's Rajagopal model is not shipped with the pip package),
   `IMUPlacer` on the first frame (base_imu_label pelvis_imu, base_heading_axis -z), then
   `IMUInverseKinematicsTool` over the whole trial.
4. Both joint-angle series against the truth (rms over the walk, after the still period), hips,
   knees and ankles, and the wall time of each tool's run.

Writes OUT/results.json and prints the table (markdown).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sensor_physics as physics  # noqa: E402

STILL, RAMP, WALK, RATE = 2.0, 1.0, 12.0, 100.0  # s, s, s, Hz
DEG = math.pi / 180
# link -> (IMU name, nominal placement: the IMU's axes in the link's frame as rpy, rad)
IMUS = {
    "Pelvis": ("pelvis_imu", (0.0, -math.pi / 2, 0.0)),  # on the sacrum: z backwards, x up
    "T8": ("torso_imu", (0.0, math.pi / 2, 0.0)),  # on the sternum: z forwards, x down
    "RightUpperLeg": ("femur_r_imu", (math.pi / 2, 0.0, 0.0)),  # lateral: z out to the right
    "RightLowerLeg": ("tibia_r_imu", (math.pi / 2, 0.0, -0.6)),  # on the tibia, turned forwards
    "RightFoot": ("calcn_r_imu", (0.0, 0.0, 0.0)),  # on the instep: z up
    "LeftUpperLeg": ("femur_l_imu", (-math.pi / 2, 0.0, 0.0)),
    "LeftLowerLeg": ("tibia_l_imu", (-math.pi / 2, 0.0, 0.6)),
    "LeftFoot": ("calcn_l_imu", (0.0, 0.0, 0.0)),
}
# the joints compared: Human48's hips, knees and ankles (both sides), by their clinical names
COMPARED = {"Hip_roty": "hip flexion", "Hip_rotx": "hip adduction", "Hip_rotz": "hip rotation",
            "Knee_roty": "knee flexion", "Knee_rotz": "knee rotation", "Ankle_roty": "ankle flexion",
            "Ankle_rotx": "ankle inversion", "Ankle_rotz": "ankle rotation"}
JOINTS = [f"j{side}{axis}" for side in ("Right", "Left") for axis in COMPARED]
OSIM_BODIES = {"Pelvis": "pelvis", "L5": "L5", "L3": "L3", "T12": "T12", "T8": "torso",
               "RightUpperLeg": "femur_r", "RightLowerLeg": "tibia_r", "RightFoot": "calcn_r",
               "LeftUpperLeg": "femur_l", "LeftLowerLeg": "tibia_l", "LeftFoot": "calcn_l"}


# ------------------------------------------------------------------------------ the walk, from standing
def smoothstep(t: np.ndarray, start: float, length: float):
    """w(t) rising from 0 (before start) to 1 (after start + length) with zero first and second
    derivatives at both ends (a quintic), its derivatives, and its integral from 0 (s)."""
    u = np.clip((t - start) / length, 0.0, 1.0)
    w = 10 * u**3 - 15 * u**4 + 6 * u**5
    dw = (30 * u**2 - 60 * u**3 + 30 * u**4) / length
    ddw = (60 * u - 180 * u**2 + 120 * u**3) / length**2
    integral = length * (2.5 * u**4 - 3 * u**5 + u**6) + np.maximum(t - start - length, 0.0)
    return w, dw, ddw, integral


@dataclass
class StandThenWalk:
    """A sensor_physics walk (straight: its turn left out) reached from standing still in `pose`
    (joint angles [n], rad): every channel is pose + w(t) (walk - pose), the speed v w(t)."""

    walk: physics.Motion
    pose: np.ndarray

    @property
    def joint_names(self):
        return self.walk.joint_names

    def joints(self, t: np.ndarray):
        return _blend(self.walk.joints(t), self.pose, t)

    def base_state(self, t: np.ndarray) -> dict[str, np.ndarray]:
        (f, l, u, y, th, ph), (df, dl, du, dy, dth, dph), (ddf, ddl, ddu, ddy, ddth, ddph) = (
            x.T for x in _blend(self.walk.base(t), np.zeros(6), t))
        w, dw, _, distance = smoothstep(t, STILL, RAMP)
        v, h = self.walk.speed, self.walk.heading0
        F, L, ez = np.array([math.cos(h), math.sin(h), 0.0]), np.array([-math.sin(h), math.cos(h), 0.0]), np.eye(3)[2]
        c = lambda x: x[:, None]  # noqa: E731
        p = c(v * distance + f) * F + c(l) * L + c(self.walk.height + u) * ez
        dp = c(v * w + df) * F + c(dl) * L + c(du) * ez
        ddp = c(v * dw + ddf) * F + c(ddl) * L + c(ddu) * ez
        R, omega, domega = physics._zyx(h + y, th, ph, dy, dth, dph, ddy, ddth, ddph)
        return dict(p=p, R=R, dp=dp, w=omega, ddp=ddp, dw=domega)


def _blend(channels, rest: np.ndarray, t: np.ndarray):
    """(x, dx, ddx) [N,n] of rest + w (x - rest) and its derivatives."""
    x, dx, ddx = channels
    w, dw, ddw, _ = smoothstep(t, STILL, RAMP)
    w, dw, ddw = w[:, None], dw[:, None], ddw[:, None]
    return rest + w * (x - rest), dw * (x - rest) + w * dx, ddw * (x - rest) + 2 * dw * dx + w * ddx


def simulate(seed: int, out: Path, walking: float = WALK) -> dict:
    """The recording written as OpenSense's two tables in `out`; returns the truth and the setup."""
    import torch

    from torchik.io.maps import reference_configuration
    from torchik.io.opensense import write_opensense
    from torchik.io.opensim_table import write_table
    from torchik.method import so3
    from torchik.method.models import load_model

    rng = np.random.default_rng([seed, 38])
    model, source = physics.human_model(48, reference=None)  # the URDF torchik ships: the tracked model's
    names, lower, upper = physics.joint_table(model)
    duration = STILL + RAMP + walking
    walk = physics.walking_motion(rng, names, lower, upper, (-0.5, duration + 0.5))
    npose = reference_configuration(load_model("human48"), "npose")[0].numpy()
    torchik_names = load_model("human48").joint_names
    pose = np.array([npose[torchik_names.index(n)] for n in walk.joint_names])
    body = physics.Body(model, StandThenWalk(walk, pose))  # type: ignore[arg-type]
    links = tuple(IMUS)
    nominal = so3.rpy_to_matrix(torch.tensor([IMUS[x][1] for x in links], dtype=torch.float64)).numpy()
    strap = physics.expm(physics.unit_vectors(rng, len(links)) * rng.uniform(3, 8, (len(links), 1)) * DEG)
    setup = physics._base_imus(links, rng)
    setup.mount[:] = nominal @ strap
    t = np.arange(int(round(duration * RATE))) / RATE
    started = time.perf_counter()
    imu = physics.simulate_imus(body, setup, t, rng=np.random.default_rng([seed, 2]))
    imu_names = [IMUS[x][0] for x in links]
    write_opensense(out / "walk_orientations.sto", t, imu_names, imu.orientation)
    gyro = (np.swapaxes(imu.orientation, -1, -2) @ imu.angular_velocity[..., None])[..., 0]  # IMU axes
    write_table(out / "walk_angular_velocity.sto", t, imu_names, gyro,
                dict(DataRate=f"{RATE:.6f}", DataType="Vec3", version="3", OpenSimVersion="4.6"))
    q = body.configuration(t)[0][:, 7:]
    error = np.degrees(np.sqrt((physics.logm(np.swapaxes(imu.true_orientation @ setup.mount, -1, -2)
                                              @ imu.orientation) ** 2).sum(-1).mean()))
    return dict(time=t, joint_names=list(walk.joint_names), joint_positions=q, urdf=source,
                filter_error_deg=float(error), strap_deg=np.degrees(np.linalg.norm(physics.logm(strap), axis=-1)).tolist(),
                simulate_s=time.perf_counter() - started, speed_m_s=walk.speed, stride_hz=walk.stride_hz)


# ------------------------------------------------------------------------------ torchik
def run_torchik(out: Path, gain: float | None = None) -> dict:
    """`torchik track` on the table (in this process, at `gain`, default torchik's), its wall time and
    the joint angles it wrote."""
    from torchik.cli import main
    from torchik.io.opensim_out import read_motion

    args = ["track", "--input", str(out / "walk_orientations.sto"), "--model", "human48", "--quiet", "--force",
            "--out", str(out / "torchik.mot"), "--out", str(out / "torchik_orientationErrors.sto"),
            "--report", str(out / "torchik_report.json")] + (["--gain", f"{gain:g}"] if gain else [])
    started = time.perf_counter()
    code = main(args)
    wall = time.perf_counter() - started
    if code != 0:
        raise SystemExit(f"torchik track exited {code}")
    motion = read_motion(out / "torchik.mot")
    report = json.loads((out / "torchik_report.json").read_text())
    timing = {"`torchik track`: read, calibrate, track, write": wall, "tracking alone (the report's wall_time_s)":
              report["wall_time_s"]}
    return dict(command="torchik " + " ".join(args), timing=timing,
                joint_names=list(motion.joint_names), joint_positions=motion.joint_positions, time=motion.time,
                base_position=report.get("base_position"), step_ms_median=report["step_time_ms"]["median"])


# ------------------------------------------------------------------------------ OpenSense
@dataclass
class UrdfJoint:
    name: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float


def urdf_joints(text: str) -> dict[str, UrdfJoint]:
    """The URDF's revolute joints by child link (Human48's joint origins have no rotation)."""
    joints = {}
    for j in ET.fromstring(text).iter("joint"):
        if j.get("type") != "revolute":
            continue
        origin = j.find("origin")
        if origin is not None and any(float(v) for v in origin.get("rpy", "0 0 0").split()):
            raise ValueError(f"joint {j.get('name')}: a rotated origin, which this builder does not handle")
        limit = j.find("limit")
        joints[j.find("child").get("link")] = UrdfJoint(
            j.get("name"), j.find("parent").get("link"), j.find("child").get("link"),
            np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]),
            np.array([float(v) for v in j.find("axis").get("xyz").split()]),
            float(limit.get("lower")), float(limit.get("upper")))
    return joints


def chain_to(link: str, joints: dict[str, UrdfJoint]) -> tuple[str, list[UrdfJoint]]:
    """The real (named) parent link of `link` and the revolute joints between them, parent first:
    Human48 splits a joint of several axes with massless links `<link>_f1`, `<link>_f2`."""
    chain = []
    current = link
    while True:
        joint = joints[current]
        chain.insert(0, joint)
        if not joint.parent.endswith(("_f1", "_f2", "_f3")):
            return joint.parent, chain
        current = joint.parent


def build_opensim_model(urdf_text: str, path: Path):
    """An OpenSim model of Human48's pelvis, trunk (to T8) and legs (to the feet), written to `path`:
    as in the URDF, a joint of several axes is a chain of single-axis joints (PinJoints about each
    joint's axis) through light bodies (`<link>_f1`, `<link>_f2`); the coordinates are named as
    Human48's joints and bounded by its limits. The pelvis is free in a frame turned so that the
    model's world is z up, as Human48's: OpenSim's ground stays y up, as OpenSense expects. Bodies:
    1 kg (0.01 kg between a joint's axes), small inertia: IMU IK is kinematic. (Built with PinJoints:
    OpenSim 4.6's Python CustomJoint constructor crashes, opensim-core issue 4166.)"""
    import opensim as osim

    joints = urdf_joints(urdf_text)
    model = osim.Model()
    model.setName("human48_legs_trunk")
    bodies: dict[str, object] = {}

    def body(link: str):
        if link not in bodies:
            light = link not in OSIM_BODIES
            bodies[link] = osim.Body(OSIM_BODIES.get(link, link), 0.01 if light else 1.0, osim.Vec3(0),
                                     osim.Inertia(*(3 * [1e-5 if light else 0.01])))
            model.addBody(bodies[link])
        return bodies[link]

    # the free joint's parent frame: torchik's z-up world in OpenSim's y-up ground (Rx(-pi/2))
    free = osim.FreeJoint("ground_pelvis", model.getGround(), osim.Vec3(0), osim.Vec3(-math.pi / 2, 0, 0),
                          body("Pelvis"), osim.Vec3(0), osim.Vec3(0))
    for k, name in enumerate(("pelvis_rotx", "pelvis_roty", "pelvis_rotz", "pelvis_tx", "pelvis_ty", "pelvis_tz")):
        free.upd_coordinates(k).setName(name)
    model.addJoint(free)
    # a PinJoint turns about its frames' z axis: frames turned so that z is the joint's axis
    z_to = {(1.0, 0.0, 0.0): osim.Vec3(0, math.pi / 2, 0), (0.0, 1.0, 0.0): osim.Vec3(-math.pi / 2, 0, 0),
            (0.0, 0.0, 1.0): osim.Vec3(0, 0, 0)}
    limits = {}
    for link in OSIM_BODIES:
        if link == "Pelvis":
            continue
        for joint in chain_to(link, joints)[1]:
            frame = z_to[tuple(float(a) for a in joint.axis)]
            pin = osim.PinJoint(joint.name, body(joint.parent), osim.Vec3(*joint.origin), frame, body(joint.child),
                                osim.Vec3(0), frame)
            pin.upd_coordinates(0).setName(joint.name)
            model.addJoint(pin)
            limits[joint.name] = (joint.lower, joint.upper)
    model.finalizeConnections()
    for name, (lower, upper) in limits.items():
        coordinate = model.updCoordinateSet().get(name)
        coordinate.setRangeMin(lower)
        coordinate.setRangeMax(upper)
    model.printToXML(str(path))
    return model


def check_opensim_model(model, urdf_text: str, seed: int = 0) -> float:
    """The largest difference (rad) between the OpenSim model's body rotations and torchik's Human48
    link rotations at a random posture: the two models' kinematics are the same."""
    import torch

    from torchik.method.kinematics import KinematicModel
    from torchik.method.so3 import log

    human = KinematicModel.from_urdf(urdf_text)
    rng = np.random.default_rng(seed)
    state = model.initSystem()
    s = torch.zeros(1, human.n_dof, dtype=torch.float64)
    coordinates = model.getCoordinateSet()
    for k in range(coordinates.getSize()):
        coordinate = coordinates.get(k)
        if coordinate.getName() in human.joint_names:
            value = rng.uniform(-0.5, 0.5)
            coordinate.setValue(state, value, False)
            s[0, human.joint_names.index(coordinate.getName())] = value
    model.realizePosition(state)
    to_z_up = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    p, R, _ = human.zero_configuration(1)
    links = tuple(OSIM_BODIES)
    with torch.no_grad():
        expected = human(p, R, s, links, jacobian=False).rotation[0].numpy()
    worst = 0.0
    for k, link in enumerate(links):
        rotation = model.getBodySet().get(OSIM_BODIES[link]).getTransformInGround(state).R()
        M = np.array([[rotation.get(i, j) for j in range(3)] for i in range(3)])
        difference = log(torch.from_numpy((to_z_up @ M).T @ expected[k])[None])[0]
        worst = max(worst, float(difference.norm()))
    return worst


def run_opensense(out: Path, urdf_text: str) -> dict:
    """OpenSense's IMU placer on the first frame and its IMU IK on the whole trial; their wall
    times and the joint angles IK wrote."""
    import opensim as osim

    from torchik.io.opensim_out import read_motion

    osim.Logger.setLevelString("warn")  # not a line per frame
    model = build_opensim_model(urdf_text, out / "human48_legs_trunk.osim")
    agreement = check_opensim_model(osim.Model(str(out / "human48_legs_trunk.osim")), urdf_text)
    rotations = osim.Vec3(-math.pi / 2, 0, 0)  # the z-up filters' world to OpenSim's ground, OpenSense's default
    started = time.perf_counter()
    placer = osim.IMUPlacer()
    placer.set_model_file(str(out / "human48_legs_trunk.osim"))
    placer.set_orientation_file_for_calibration(str(out / "walk_orientations.sto"))
    placer.set_sensor_to_opensim_rotations(rotations)
    placer.set_base_imu_label("pelvis_imu")
    placer.set_base_heading_axis("-z")
    placer.run(False)
    placer.getCalibratedModel().printToXML(str(out / "calibrated.osim"))
    placed = time.perf_counter()
    ik = osim.IMUInverseKinematicsTool()
    ik.set_model_file(str(out / "calibrated.osim"))
    ik.set_orientations_file(str(out / "walk_orientations.sto"))
    ik.set_sensor_to_opensim_rotations(rotations)
    ik.set_results_directory(str(out / "opensense"))
    ik.set_time_range(0, 0.0)
    ik.set_time_range(1, 1e9)
    ik.run(False)
    done = time.perf_counter()
    motion = read_motion(out / "opensense" / "ik_walk_orientations.mot")
    del model
    timing = {"IMUPlacer and IMUInverseKinematicsTool": done - started, "IMUInverseKinematicsTool alone": done - placed}
    return dict(timing=timing, model_agreement_rad=agreement,
                joint_names=list(motion.joint_names), joint_positions=motion.joint_positions, time=motion.time,
                version=osim.GetVersion() if hasattr(osim, "GetVersion") else osim.__version__)


# ------------------------------------------------------------------------------ the comparison
def errors(estimate: dict, truth: dict) -> dict[str, float]:
    """rms (deg) of each compared joint's error over the walk (after the still period and the ramp's start)."""
    walking = truth["time"] >= STILL
    out = {}
    for joint in JOINTS:
        est = estimate["joint_positions"][:, estimate["joint_names"].index(joint)]
        true = truth["joint_positions"][:, truth["joint_names"].index(joint)]
        n = min(len(est), len(true))
        e = (est[:n] - true[:n])[walking[:n]]
        out[joint] = float(np.degrees(np.sqrt(np.mean(e**2))))
    return out


def orientation_errors(path: Path) -> dict[str, float]:
    """rms (deg) of each IMU's column of an orientation-error table (rad), over the walk."""
    from torchik.io.opensim_table import read_table

    errors = read_table(path)
    walking = errors.time >= STILL
    return {imu: float(np.degrees(np.sqrt(np.nanmean(errors.column(imu, 1)[walking, 0] ** 2)))) for imu in errors.labels}


def table(truth: dict, results: dict[str, dict]) -> str:
    """The markdown tables: rms error per joint and side against the truth, then each tool's speed."""
    frames, tools = len(truth["time"]), list(results)
    lines = ["| deg rms over the walk | " + " | ".join(f"{tool} right | {tool} left" for tool in tools) + " |",
             "|---|" + "---:|" * (2 * len(tools))]
    for axis, label in COMPARED.items():
        cells = [f"{results[tool]['errors'][f'j{side}{axis}']:.2f}" for tool in tools for side in ("Right", "Left")]
        lines.append(f"| {label} (`{axis}`) | " + " | ".join(cells) + " |")
    imus = list(results[tools[0]]["orientation_errors"])
    lines += ["", "| orientation error, deg rms over the walk | " + " | ".join(imus) + " |", "|---|" + "---:|" * len(imus)]
    for tool in tools:
        lines.append(f"| {tool} | " + " | ".join(f"{results[tool]['orientation_errors'][imu]:.3f}" for imu in imus) + " |")
    lines += ["", "| tool | what the time covers | wall s | frames per second |", "|---|---|---:|---:|"]
    for tool, result in results.items():
        for what, seconds in result["timing"].items():
            lines.append(f"| {tool} | {what} | {seconds:.2f} | {frames / seconds:.0f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("opensense_run"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--walk", type=float, default=WALK, help=f"seconds of walking (default {WALK:g})")
    parser.add_argument("--gain", type=float, help="torchik's gain K (1/s; default torchik track's)")
    parser.add_argument("--no-opensim", action="store_true", help="torchik only (OpenSim not installed)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    import torch

    torch.set_num_threads(1)
    truth = simulate(args.seed, args.out, args.walk)
    print(f"simulated {len(truth['time'])} frames ({truth['simulate_s']:.0f} s): IMU filters "
          f"{truth['filter_error_deg']:.2f} deg rms from the truth; straps {np.round(truth['strap_deg'], 1).tolist()} deg")
    results = {"torchik": run_torchik(args.out, args.gain)}
    if not args.no_opensim:
        results["OpenSense"] = run_opensense(args.out, _urdf_text())
        print(f"OpenSim model against torchik's Human48: {results['OpenSense']['model_agreement_rad']:.1e} rad")
    for result in results.values():
        result["errors"] = errors(result, truth)
    results["torchik"]["orientation_errors"] = orientation_errors(args.out / "torchik_orientationErrors.sto")
    if "OpenSense" in results:  # its IMU IK's own table, column by column beside torchik's
        results["OpenSense"]["orientation_errors"] = orientation_errors(
            args.out / "opensense" / "ik_walk_orientations_orientationErrors.sto")
    print(table(truth, results))
    keep = lambda r: {k: v for k, v in r.items() if k not in ("joint_positions", "time", "joint_names")}  # noqa: E731
    summary = dict(seed=args.seed, gain=args.gain, frames=len(truth["time"]), rate_hz=RATE, still_s=STILL, ramp_s=RAMP,
                   walk_s=args.walk, filter_error_deg=truth["filter_error_deg"], strap_deg=truth["strap_deg"],
                   speed_m_s=truth["speed_m_s"], stride_hz=truth["stride_hz"],
                   results={tool: keep(r) for tool, r in results.items()}, table=table(truth, results))
    (args.out / "results.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {args.out / 'results.json'}")


def _urdf_text() -> str:
    from torchik.method.models import human_urdf

    return human_urdf(48)


if __name__ == "__main__":
    main()
