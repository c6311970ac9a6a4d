"""Time inverse dynamics, torchik (batched) against a per-configuration loop of pinocchio's rnea.

For each model (Human66, Human48, iCub) and B = 1, 64, 1024 random states (base pose, joint angles
within the limits, velocities, accelerations; gravity, no contact), it reports the fastest of
repeated calls (the one the machine's other work disturbed least) of `tk.inverse_dynamics` for the
whole batch and of a Python loop calling
`pinocchio.rnea` once per state (the states turned to pinocchio's convention before the clock
starts), and their ratio. Both are checked to give the same forces (1e-9) before timing.
torchik.memory's `keep_freed_memory()` is on, as in `torchik bench` (see that module for why).

    python experiments/bench_dynamics.py [--threads 2] [--batches 1 64 1024] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import timeit

import numpy as np
import torch

from torchik.method import so3
from torchik.method.dynamics import inverse_dynamics
from torchik.method.models import human_urdf, icub_urdf_path, load_model
from torchik.pipelines.memory import keep_freed_memory


def best_time(fn, repeats: int) -> float:
    """The fastest of `repeats` calls after two unmeasured ones: on a shared machine, the call least
    disturbed by the others' work."""
    return min(timeit.repeat(fn, number=1, repeat=repeats + 2)[2:])


def random_states(model, B: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    kw = dict(generator=g, dtype=torch.float64)
    s = model.lower + (model.upper - model.lower) * torch.rand(B, model.n_dof, **kw)
    return (torch.randn(B, 3, **kw), so3.random_rotation((B,), g), s, torch.randn(B, 6 + model.n_dof, **kw),
            torch.randn(B, 6 + model.n_dof, **kw))


def pinocchio_arrays(pin, reference, model, p, R, s, nu, nu_dot):
    """q [B,nq], v, a [B,nv] in pinocchio's convention (base velocity in the base frame; its
    acceleration the derivative of that), and the joints' rows of v."""
    joints = [reference.joints[reference.getJointId(name)] for name in model.joint_names]
    iq, iv = [j.idx_q for j in joints], [j.idx_v for j in joints]
    B = p.shape[0]
    Rt = R.transpose(1, 2).numpy()
    turn = lambda x: np.einsum("bij,bj->bi", Rt, x.numpy())  # noqa: E731
    v_l, w_l = turn(nu[:, :3]), turn(nu[:, 3:6])
    q, v, a = np.zeros((B, reference.nq)), np.zeros((B, reference.nv)), np.zeros((B, reference.nv))
    q[:, :3], q[:, iq] = p.numpy(), s.numpy()
    q[:, 3:7] = [pin.Quaternion(Rb).coeffs() for Rb in R.numpy()]
    v[:, :3], v[:, 3:6], v[:, iv] = v_l, w_l, nu[:, 6:].numpy()
    a[:, :3], a[:, 3:6] = turn(nu_dot[:, :3]) - np.cross(w_l, v_l), turn(nu_dot[:, 3:6])
    a[:, iv] = nu_dot[:, 6:].numpy()
    return q, v, a, iv


def measure(pin, name: str, model, reference, B: int) -> dict:
    """torchik's batched call and pinocchio's loop over B states, checked against each other first."""
    data = reference.createData()
    p, R, s, nu, nu_dot = random_states(model, B, seed=B)
    q, v, a, iv = pinocchio_arrays(pin, reference, model, p, R, s, nu, nu_dot)
    ours = inverse_dynamics(model, p, R, s, nu, nu_dot).forces[0].numpy()
    tau = pin.rnea(reference, data, q[0], v[0], a[0])
    theirs = np.concatenate((R[0].numpy() @ tau[:3], R[0].numpy() @ tau[3:6], tau[iv]))
    assert np.abs(ours - theirs).max() < 1e-9, "pinocchio and torchik disagree"

    def loop():
        for b in range(B):
            pin.rnea(reference, data, q[b], v[b], a[b])

    repeats = max(5, min(200, 20000 // B))
    batched = best_time(lambda: inverse_dynamics(model, p, R, s, nu, nu_dot), repeats)
    looped = best_time(loop, max(3, repeats // 4))
    return dict(model=name, batch=B, torchik_ms=batched * 1e3, pinocchio_loop_ms=looped * 1e3, speedup=looped / batched)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads (default 2)")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024])
    parser.add_argument("--models", nargs="+", default=["human66", "human48", "icub"])
    parser.add_argument("--json", help="write the results here as JSON")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    keep_freed_memory()
    import pinocchio as pin

    rows = []
    for name in args.models:
        model = load_model(name)
        text = open(icub_urdf_path()).read() if name == "icub" else human_urdf(int(name[-2:]))
        reference = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        rows += [measure(pin, name, model, reference, B) for B in args.batches]

    print(f"inverse dynamics, float64, {args.threads} torch threads, {platform.processor() or platform.machine()}")
    print(f"{'model':8s} {'B':>6} | {'torchik ms':>10} {'us/state':>9} | {'pinocchio loop ms':>17} {'us/state':>9} | "
          f"{'loop / torchik':>14}")
    for r in rows:
        B = r["batch"]
        print(f"{r['model']:8s} {B:>6} | {r['torchik_ms']:>10.3f} {r['torchik_ms'] * 1e3 / B:>9.2f} | "
              f"{r['pinocchio_loop_ms']:>17.3f} {r['pinocchio_loop_ms'] * 1e3 / B:>9.2f} | {r['speedup']:>13.2f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(threads=args.threads, rows=rows), f, indent=2)


if __name__ == "__main__":
    main()
