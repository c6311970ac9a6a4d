"""`torchik bench --dynamics`: B configurations' inverse dynamics, torchik's batched call against a
per-configuration loop of pinocchio's rnea.

For each model (Human48, Human66, iCub), device and batch size B, B random states (base pose, joint
angles within the limits, velocities, accelerations; gravity, no contact) are turned to pinocchio's
convention before any clock starts. Both are first checked to give the same forces (1e-9 N and N m
in float64, 1e-4 of the largest in float32, on 16 of the rows); then the fastest of repeated calls
(the one the machine's other work disturbed least) is kept: of `tk.inverse_dynamics` for the whole
batch, of `CompiledInverseDynamics` with --compile (its capture timed apart, not in the call), and of
a Python loop calling `pinocchio.rnea` once per state, and the ratio of the loop's time to torchik's.
pinocchio runs on the CPU in float64 whatever torchik's device and dtype.

    torchik bench --dynamics [--models human48 human66 icub] [--batch 1024] [--compile] [--json out.json]
"""

from __future__ import annotations

import timeit
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ..errors import optional
from ..method import so3
from ..method.dynamics import inverse_dynamics
from ..method.models import human_urdf, icub_urdf_path, load_model

BATCHES = (1024,)
MODELS = ("human48", "human66", "icub")
CHECKED = 16  # rows compared with pinocchio before timing


@dataclass
class DynamicsMeasurement:
    """One model, device and batch: the fastest call's time (ms) of torchik eager, torchik compiled
    (None without --compile) and the pinocchio loop; compile_seconds the capture's; difference the
    largest gap to pinocchio's forces (N, N m) on the checked rows."""

    model: str
    device: str
    dtype: str
    batch: int
    torchik_ms: float
    pinocchio_loop_ms: float
    difference: float
    compiled_ms: float | None = None
    compile_seconds: float | None = None

    @property
    def speedup(self) -> float:
        return self.pinocchio_loop_ms / self.torchik_ms

    @property
    def compiled_speedup(self) -> float | None:
        return None if self.compiled_ms is None else self.pinocchio_loop_ms / self.compiled_ms


def best_time(fn, repeats: int, device: str = "cpu") -> float:
    """The fastest of `repeats` calls after two unmeasured ones (s): on a shared machine, the call least
    disturbed by the others' work. On CUDA each call is synchronised."""
    cuda = torch.device(device).type == "cuda"

    def call():
        fn()
        if cuda:
            torch.cuda.synchronize()

    return min(timeit.repeat(call, number=1, repeat=repeats + 2)[2:])


def random_states(model, B: int, seed: int):
    """B random states, float64 on the CPU: p [B,3], R [B,3,3], s [B,n] within the limits, velocity and
    acceleration [B,6+n]."""
    g = torch.Generator().manual_seed(seed)
    kw: dict[str, Any] = dict(generator=g, dtype=torch.float64)
    s = model.lower.cpu() + (model.upper - model.lower).cpu() * torch.rand(B, model.n_dof, **kw)
    return (torch.randn(B, 3, **kw), so3.random_rotation((B,), g), s, torch.randn(B, 6 + model.n_dof, **kw),
            torch.randn(B, 6 + model.n_dof, **kw))


def pinocchio_model(pin, name: str):
    """pinocchio's model of a torchik model, built from the same URDF with a free flyer."""
    text = open(icub_urdf_path()).read() if name == "icub" else human_urdf(int(name[-2:]))
    return pin.buildModelFromXML(text, pin.JointModelFreeFlyer())


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


def measure(pin, name: str, B: int, device: str = "cpu", dtype=torch.float64, compiled: bool = False,
            repeats: int | None = None) -> DynamicsMeasurement:
    """torchik's batched call (and compiled, with `compiled`) and pinocchio's loop over B states,
    checked against each other first."""
    model = load_model(name, dtype=dtype, device=device)
    reference = pinocchio_model(pin, name)
    data = reference.createData()
    state = random_states(model, B, seed=B)
    q, v, a, iv = pinocchio_arrays(pin, reference, model, *state)
    ours_state = [x.to(device=device, dtype=dtype) for x in state]
    ours = inverse_dynamics(model, *ours_state).forces.double().cpu().numpy()
    R = state[1].numpy()
    rows = np.unique(np.linspace(0, B - 1, min(B, CHECKED)).astype(int))
    theirs = []
    for b in rows:
        tau = pin.rnea(reference, data, q[b], v[b], a[b])
        theirs.append(np.concatenate((R[b] @ tau[:3], R[b] @ tau[3:6], tau[iv])))
    difference = float(np.abs(ours[rows] - np.array(theirs)).max())
    tolerance = 1e-9 if dtype == torch.float64 else 1e-4 * float(np.abs(theirs).max())
    if not difference <= tolerance:
        raise AssertionError(f"{name} on {device}: torchik and pinocchio differ by {difference:.3g} (> {tolerance:.3g})")

    def loop():
        for b in range(B):
            pin.rnea(reference, data, q[b], v[b], a[b])

    repeats = repeats or max(5, min(200, 20000 // B))
    batched = best_time(lambda: inverse_dynamics(model, *ours_state), repeats, device)
    looped = best_time(loop, max(3, repeats // 4))
    out = DynamicsMeasurement(name, device, str(dtype).removeprefix("torch."), B, batched * 1e3, looped * 1e3,
                              difference)
    if compiled:
        from ..method.dynamics.compiled import CompiledInverseDynamics

        fn = CompiledInverseDynamics(model, B)
        gap = float((fn(*ours_state) - torch.from_numpy(ours).to(device=device, dtype=dtype)).abs().max())
        if not gap <= max(tolerance, 1e-9):
            raise AssertionError(f"{name} on {device}: compiled and eager differ by {gap:.3g}")
        out.compiled_ms = best_time(lambda: fn(*ours_state), repeats, device) * 1e3
        out.compile_seconds = fn.compile_seconds
    return out


def run(models=MODELS, batches=BATCHES, devices=("cpu",), dtype=torch.float64, compiled: bool = False,
        progress: bool = True) -> list[DynamicsMeasurement]:
    """Every measurement, model by model, device by device, batch by batch."""
    pin = optional("pinocchio", "bench", "torchik bench --dynamics (its peer is pinocchio's rnea)")
    plan = [(name, device, B) for name in models for device in devices for B in batches]
    from tqdm import tqdm

    results = []
    with tqdm(plan, desc="bench --dynamics", unit="run", leave=False, disable=not progress) as bar:
        for name, device, B in bar:
            bar.set_postfix_str(f"{name} {device} B={B}")
            results.append(measure(pin, name, B, device, dtype, compiled))
    return results


def table(results: list[DynamicsMeasurement]) -> str:
    """The measurements as a table: each call's time and per state, and the loop's time over torchik's."""
    compiled = any(r.compiled_ms is not None for r in results)
    head = (f"{'model':8s} {'device':6s} {'B':>6s} | {'torchik ms':>10s} {'us/state':>9s} | "
            + (f"{'compiled ms':>11s} {'us/state':>9s} | " if compiled else "")
            + f"{'pinocchio loop ms':>17s} {'us/state':>9s} | {'loop/torchik':>12s}"
            + (f" {'loop/compiled':>13s}" if compiled else ""))
    lines = [head]
    for r in results:
        line = f"{r.model:8s} {r.device:6s} {r.batch:>6d} | {r.torchik_ms:>10.3f} {1e3 * r.torchik_ms / r.batch:>9.2f} | "
        if compiled:
            line += "-" if r.compiled_ms is None else f"{r.compiled_ms:>11.3f} {1e3 * r.compiled_ms / r.batch:>9.2f}"
            line += " | "
        line += (f"{r.pinocchio_loop_ms:>17.3f} {1e3 * r.pinocchio_loop_ms / r.batch:>9.2f} | "
                 f"{r.speedup:>11.2f}x")
        if compiled:
            line += "" if r.compiled_speedup is None else f" {r.compiled_speedup:>12.2f}x"
        lines.append(line)
    lines.append("the fastest of repeated calls; torchik checked against pinocchio first (largest difference "
                 f"{max(r.difference for r in results):.1e})")
    captures = [f"{r.model} {r.device} B={r.batch} {r.compile_seconds:.1f} s" for r in results
                if r.compile_seconds is not None]
    if captures:
        lines.append("compiled, the capture's time (not timed): " + ", ".join(captures))
    return "\n".join(lines)
