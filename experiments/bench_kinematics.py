"""Time poses + Jacobians of Human66's 23 segments per call, torchik (batched) vs a pinocchio loop.

For B = 1, 64, 1024 configurations it reports the median time of repeated calls and the time
per configuration of:
- torchik, allocating its outputs each call (`model(p, R, s, links)`),
- torchik writing into reused buffers (`out=`), as the tracker does every step,
- pinocchio in a per-configuration loop: forwardKinematics + computeJointJacobians +
  updateFramePlacements + getFrameJacobian(LOCAL_WORLD_ALIGNED) for the same 23 frames,
  the fastest CPU pipeline a user could assemble from an existing library.
Both are checked to compute the same link positions before timing. torchik.memory's
`keep_freed_memory()` is on unless `--system-allocator` is given (see that module for why).

    python experiments/bench_kinematics.py [--threads 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import numpy as np
import torch

from torchik.method import so3
from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.memory import keep_freed_memory


def median_time(fn, repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def pinocchio_loop(model, links, p, R, s):
    """A closure that runs pinocchio over the batch, one configuration at a time."""
    import pinocchio as pin

    pm = pin.buildModelFromXML(human_urdf(66), pin.JointModelFreeFlyer())
    data = pm.createData()
    frames = [pm.getFrameId(name) for name in links]
    # pinocchio orders joints depth-first; map torchik's joint order onto its q vector
    idx_q = [pm.joints[pm.getJointId(name)].idx_q for name in model.joint_names]
    qs = np.zeros((p.shape[0], pm.nq))
    for b in range(p.shape[0]):
        qs[b, :3] = p[b].numpy()
        qs[b, 3:7] = pin.Quaternion(R[b].numpy()).coeffs()
        qs[b, idx_q] = s[b].numpy()

    def run():
        out = []
        for q in qs:
            pin.forwardKinematics(pm, data, q)
            pin.computeJointJacobians(pm, data, q)
            pin.updateFramePlacements(pm, data)
            out.append([pin.getFrameJacobian(pm, data, f, pin.LOCAL_WORLD_ALIGNED) for f in frames])
        return out

    def positions(b):
        pin.forwardKinematics(pm, data, qs[b])
        pin.updateFramePlacements(pm, data)
        return np.stack([data.oMf[f].translation for f in frames])

    return run, positions


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads (default 2)")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    parser.add_argument("--json", help="write the results here as JSON")
    parser.add_argument("--system-allocator", action="store_true",
                        help="leave glibc malloc as it is (by default torchik.keep_freed_memory() is on)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    kept = False if args.system_allocator else keep_freed_memory()

    model = load_model("human66")
    links = TRACKED_LINKS["human66"]
    selection = model.select(links)
    rows = []
    for B in args.batches:
        g = torch.Generator().manual_seed(B)
        p = torch.randn(B, 3, generator=g, dtype=torch.float64)
        R = so3.random_rotation((B,), g)
        s = torch.randn(B, model.n_dof, generator=g, dtype=torch.float64)
        repeats = max(5, min(200, 20000 // B))
        buffers = model.empty_output(B, selection)
        fresh = median_time(lambda p=p, R=R, s=s: model(p, R, s, selection), repeats)
        reused = median_time(lambda p=p, R=R, s=s, out=buffers: model(p, R, s, selection, out=out), repeats)
        row = dict(batch=B, torchik_ms=fresh * 1e3, torchik_out_ms=reused * 1e3)
        try:
            run, positions = pinocchio_loop(model, links, p, R, s)
        except ImportError:
            run = None
        if run is not None:
            ours = model(p, R, s, selection, jacobian=False).position
            assert np.abs(positions(0) - ours[0].numpy()).max() < 1e-9, "pinocchio and torchik disagree"
            row["pinocchio_ms"] = median_time(run, max(3, repeats // 4), warmup=1) * 1e3
        rows.append(row)

    print(f"Human66, {len(links)} links, poses + Jacobians [B,23,6,72], float64, {args.threads} torch threads, "
          f"{platform.processor() or platform.machine()}, keep_freed_memory={kept}")
    print(f"{'B':>6} | {'torchik ms':>10} {'us/conf':>8} | {'torchik out= ms':>15} {'us/conf':>8} | "
          f"{'pinocchio loop ms':>17} {'us/conf':>8}")
    for r in rows:
        B = r["batch"]
        pin_ms = r.get("pinocchio_ms", float("nan"))
        print(f"{B:>6} | {r['torchik_ms']:>10.3f} {r['torchik_ms'] * 1e3 / B:>8.2f} | "
              f"{r['torchik_out_ms']:>15.3f} {r['torchik_out_ms'] * 1e3 / B:>8.2f} | "
              f"{pin_ms:>17.3f} {pin_ms * 1e3 / B:>8.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(threads=args.threads, links=len(links), keep_freed_memory=kept, rows=rows), f, indent=2)


if __name__ == "__main__":
    main()
