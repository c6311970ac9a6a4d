"""IMU recordings whose angular velocities a user derived from the orientations, through `torchik diagnose`.

    python experiments/diagnosis_derived.py [--out DIR]

A user converting a file of IMU orientations (OpenSense's quaternion table, an MVNX file without its
gyros) often derives the angular velocity by differentiating them. The diagnosis must tell that from
the data, whatever the file says, fit no gyro family, and list in its first lines only effects above
their floor. Two recordings, each saved as a plain `.npz` (no metadata saying how its rates were
made) and diagnosed by the command as a user would:

- the shared MVNX file (../shared/data/mvnx/test_mocap.mvnx, Xsens MVN, upper body), its angular
  velocity replaced by 2 dq/dt q* with dq/dt by np.gradient of the quaternions;
- a simulated suit of 8 IMUs (pelvis, thighs, shanks, feet and T8, as an OpenSense lower-body set:
  experiments/sensor_physics.py, seed 3000), its rates derived the same way, with one shank's strap
  turned by 12 deg.

For each it prints whether any link was taken for a gyro, the gyro candidates fitted (none expected),
the report's first lines (report.md up to "Model:") and whether every effect they list is above its
floor (the report's "Significant but negligible" section holds the others).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DATA = HERE.parents[1] / "shared" / "data"
GYRO_KINDS = ("gyro_bias", "gyro_scale", "stream_delay")
LOWER_BODY = ("Pelvis", "T8", "RightUpperLeg", "RightLowerLeg", "RightFoot", "LeftUpperLeg", "LeftLowerLeg", "LeftFoot")


def quaternion_rates(R: np.ndarray, time: np.ndarray) -> np.ndarray:
    """[T,L,3] world rates 2 dq/dt q*, dq/dt by np.gradient of the quaternions (w, x, y, z; made
    continuous in sign): how a user differentiates orientations, not the project's scheme."""
    from scipy.spatial.transform import Rotation

    T, L = R.shape[:2]
    q = Rotation.from_matrix(np.nan_to_num(R.reshape(-1, 3, 3), nan=0.0) + np.isnan(R.reshape(-1, 3, 3)) * np.eye(3)
                             ).as_quat(scalar_first=True).reshape(T, L, 4)
    for k in range(1, T):
        q[k] = np.where(((q[k] * q[k - 1]).sum(-1) < 0)[:, None], -q[k], q[k])
    dq = np.gradient(q, time, axis=0)
    s, v, ds, dv = q[..., 0], q[..., 1:], dq[..., 0], dq[..., 1:]
    return 2.0 * (s[..., None] * dv - ds[..., None] * v - np.cross(dv, v))


def mvnx_derived(out: Path) -> Path | None:
    from torchik.io import read, save_recording
    from torchik.pipelines.diagnosis.effect import replace

    path = DATA / "mvnx" / "test_mocap.mvnx"
    if not path.is_file():
        return None
    recording = read(str(path))
    derived = replace(recording, angular_velocity=quaternion_rates(recording.orientation, recording.time), meta={})
    return save_recording(derived, out / "mvnx_derived.npz")


def suit_derived(out: Path) -> Path:
    sys.path.insert(0, str(HERE))
    from sensor_physics import generate

    from torchik.io import save_recording
    from torchik.pipelines.diagnosis.effect import replace

    recording, injected, _ = generate(3000, "strap", 1, LOWER_BODY, reference=None)
    print(f"  simulated: {injected[0].targets[0]} strap turned {injected[0].sizes[0]:.1f} deg")
    derived = replace(recording, angular_velocity=quaternion_rates(recording.orientation, recording.time), meta={})
    return save_recording(derived, out / "suit_derived.npz")


def diagnosed(path: Path, out: Path) -> dict:
    report = out / (path.stem + "_report")
    run = subprocess.run([sys.executable, "-m", "torchik", "diagnose", str(path), "--model", "human48", "--report",
                          str(report), "--force", "--no-rrd"], capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(run.stderr)
    summary = json.loads((report / "diagnosis.json").read_text())
    first = (report / "report.md").read_text().split("Model:")[0]
    gyro_fitted = [e for e in summary["effects"] + summary["rejected"] + summary["negligible"] if e["kind"] in GYRO_KINDS]
    unfitted = {e["kind"] for e in summary["unobservable"] if "derivative" in e["notes"]}
    from torchik.pipelines.diagnosis.calibration import EFFECT_TYPES

    dt = float(np.median(np.diff(np.load(path)["time"])))
    sizes = [EFFECT_TYPES[e["kind"]](e["kind"], e["target"], e["params"]).below_floor(dt) for e in summary["effects"]]
    return dict(file=path.name, gyro_fitted=len(gyro_fitted), said_derived=sorted(unfitted & set(GYRO_KINDS)),
                kept=[f"{e['kind']} at {e['target']}" for e in summary["effects"]], all_above_floor=not any(sizes),
                negligible=len(summary["negligible"]), first_lines=first.strip())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", help="where the recordings and reports go (default a temporary folder)")
    args = parser.parse_args(argv)
    out = Path(args.out or tempfile.mkdtemp(prefix="derived_"))
    out.mkdir(parents=True, exist_ok=True)
    paths = [p for p in (mvnx_derived(out), suit_derived(out)) if p is not None]
    for path in paths:
        r = diagnosed(path, out)
        print(f"{r['file']}: gyro candidates fitted {r['gyro_fitted']}; said not identifiable for the derivative: "
              f"{', '.join(r['said_derived'])}; kept {r['kept'] or 'nothing'}; every kept effect above its floor: "
              f"{r['all_above_floor']}; negligible listed apart: {r['negligible']}")
        print("  " + r["first_lines"].replace("\n", "\n  "))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
