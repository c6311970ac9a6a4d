"""`torchik bench --profile`: where a batched step's time goes, phase by phase, against this
machine's roofline.

Every tensor operation of a few tracker steps is intercepted (a `TorchDispatchMode`), timed, and
counted, and charged to the step's phase that called it (the innermost function of `PHASES` on the
Python stack): targets and scheme, kinematics, residuals, normal equations, bounds, the QP
(factorisations, solves, the rows' Schur complement, the rest), integration, diagnostics.

- Bytes moved: the memory footprint of each operation's tensor inputs and outputs, each read or
  written once (a broadcast input counts its stored elements, a view nothing; a gather its output
  twice, a scatter its source three times: the rows it reads, and the target's rows it reads and
  writes). A lower bound on the traffic, exact for the streaming elementwise kernels that most of
  the step is.
- Floating-point operations, from the shapes: matrix products 2 m n k (times the batch; addmm and
  baddbmm m n more), Cholesky factorisations n^3/3 per matrix, Cholesky solves 2 n^2 k, triangular
  solves n^2 k, LU-based solves 2 n^3/3 + 2 n^2 k; elementwise operations one per output element
  (addcmul, addcdiv, lerp: two; comparisons, selections and transcendental functions count one);
  reductions one per input element; cross products three per output element; index_add one per
  added element; copies, gathers, scatters and creations none.

The peaks are measured in the same run: a float64 matrix product of two 1024 x 1024 matrices
(GFLOP/s) and a copy of a 128 MiB tensor (GB/s, the read and the write counted). A phase's
roofline bound is min(peak flop rate, its flops per byte x peak bandwidth); the fraction is its
achieved flop rate over that bound (above 100 % where a phase's data stays in cache, faster than
the copy's memory). The operations' times are taken with the profiler on, which slows the
cheapest operations most; the step's plain wall time, measured on other steps of the same run
without the profiler, heads the table.

    torchik bench --models human66 --batch 1024 --no-loops --profile
"""

from __future__ import annotations

import math
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_leaves


@dataclass
class Phase:
    """One phase's totals over the profiled steps: seconds in its operations, flops, bytes, operations."""

    name: str
    seconds: float = 0.0
    flops: float = 0.0
    bytes: float = 0.0
    operations: int = 0


@dataclass
class Peaks:
    """The machine's measured peaks: float64 matmul GFLOP/s and stream-copy GB/s."""

    gflops: float
    gbytes: float


@dataclass
class Profile:
    model: str
    batch: int
    dtype: str
    steps: int
    wall_seconds: float  # the profiled steps' wall time without the profiler (a separate timing)
    peaks: Peaks
    phases: list[Phase] = field(default_factory=list)


def phase_functions() -> dict:
    """The code object of each function that starts a phase -> the phase's name."""
    from ..method import integrate, metrics, residual, scheme, step_kinematics, step_problem, target_equations, targets
    from ..method.limits import velocity_bounds
    from ..method.qp import active_set, base, rows, tree
    from ..method.qp.batched import BatchedBackend
    from ..method.qp.dense import DenseFactor
    from ..method.qp.interior_point import interior_point
    from ..method.tracker import DynamicalIK

    phases: dict[str, list[Any]] = {
        "targets and scheme": [targets.clean_targets, scheme.SchemeHistory.evaluate, DynamicalIK._check_targets,
                               DynamicalIK._time_step],
        "kinematics": [step_kinematics.step_kinematics],
        "residuals": [residual.position_residual, residual.orientation_residual, residual.corrected_velocity],
        "normal equations": [target_equations.normal_equations, tree.TreeHessian.from_targets],
        "bounds": [velocity_bounds, step_problem._coupled_rows],
        "qp: factorisation": [tree.TreeFactor.__init__, DenseFactor.__init__],
        "qp: solves": [tree.TreeFactor.solve, DenseFactor.solve, tree.TreeHessian.matvec],
        "qp: rows": [rows.optimal_rows, active_set._with_rows],
        "qp: rest": [BatchedBackend.solve, interior_point, base.clipped_fallback],
        "integration": [integrate.integrate, integrate.orthonormalize, scheme.SchemeHistory.advance,
                        DynamicalIK._check_invariant],
        "diagnostics": [metrics.orientation_error, base.QPProblem.active],
    }
    return {f.__code__: name for name, functions in phases.items() for f in functions}


ORDER = ("targets and scheme", "kinematics", "residuals", "normal equations", "bounds", "qp: factorisation",
         "qp: solves", "qp: rows", "qp: rest", "integration", "diagnostics", "other")


def _footprint(t: torch.Tensor) -> int:
    """Bytes a tensor occupies in memory: its stored elements (a broadcast dimension stores one)."""
    stored = math.prod(size for size, stride in zip(t.shape, t.stride()) if stride != 0)
    return stored * t.element_size()


GATHERS = ("index_select", "index", "gather", "take", "masked_select")
SCATTERS = ("index_add", "index_copy", "index_put", "index_fill", "scatter", "scatter_add", "masked_scatter")


def operation_bytes(func, args, kwargs, out) -> float:
    """Bytes one aten operation reads and writes: its tensors' footprints; a gather reads only
    what it selects (its output) and a scatter touches only the rows it writes (its source)."""
    name = func.overloadpacket.__name__.rstrip("_")
    tensors = [t for t in tree_leaves((args, kwargs)) if isinstance(t, torch.Tensor)]
    outputs = [t for t in tree_leaves(out) if isinstance(t, torch.Tensor)]
    indices = sum(_footprint(t) for t in tensors if not t.is_floating_point())
    if name in GATHERS and outputs:
        return 2 * _footprint(outputs[0]) + indices
    if name in SCATTERS and tensors:
        source = max((t for t in tensors[1:] if t.is_floating_point()), key=_footprint, default=None)
        return (3 * _footprint(source) if source is not None else 0) + indices
    return float(sum(_footprint(t) for t in tensors + outputs))


def operation_flops(func, args, kwargs, out) -> float:
    """Floating-point operations of one aten operation, from its shapes (see the module's docstring)."""
    name = func.overloadpacket.__name__
    tensors = [t for t in tree_leaves((args, kwargs)) if isinstance(t, torch.Tensor)]
    outputs = [t for t in tree_leaves(out) if isinstance(t, torch.Tensor)]
    if not outputs or not outputs[0].is_floating_point():
        return 0.0
    if not tensors:
        return 0.0
    a, result = tensors[0], outputs[0]
    if name in ("mm", "addmm", "bmm", "baddbmm"):
        left, right = (tensors[1], tensors[2]) if name in ("addmm", "baddbmm") else (tensors[0], tensors[1])
        k = left.shape[-1]
        return result.numel() * (2 * k + (1 if name in ("addmm", "baddbmm") else 0))
    if name == "linalg_cholesky_ex":
        n = a.shape[-1]
        return a.numel() / (n * n) * n ** 3 / 3
    if name in ("cholesky_solve", "_cholesky_solve_helper", "linalg_solve_triangular", "triangular_solve"):
        n = a.shape[-2]
        per_triangle = n * result.numel()  # n^2 k per matrix: the result holds n k per matrix
        return per_triangle * (2 if "cholesky" in name else 1)
    if name in ("linalg_solve_ex", "_linalg_solve_ex", "linalg_lu_factor_ex", "lu_solve", "linalg_lu_solve"):
        n = tensors[0].shape[-1]
        return tensors[0].numel() / (n * n) * 2 * n ** 3 / 3 + 2 * n * result.numel()
    if name in ("linalg_cross", "cross"):
        return 3 * result.numel()
    if name in ("index_add", "index_add_"):
        return tensors[2].numel() if len(tensors) > 2 else 0.0
    if torch.Tag.reduction in func.tags:
        return float(a.numel())
    if torch.Tag.pointwise in func.tags:
        return (2 if name.rstrip("_") in ("addcmul", "addcdiv", "lerp") else 1) * result.numel()
    return 0.0


class _Counter(TorchDispatchMode):
    """Times and counts every operation, charged to the innermost phase function on the stack."""

    def __init__(self, functions: dict):
        super().__init__()
        self.functions = functions
        self.phases: dict[str, Phase] = defaultdict(lambda: Phase(""))

    def _phase(self) -> str:
        frame: FrameType | None = sys._getframe(2)
        while frame is not None:
            name = self.functions.get(frame.f_code)
            if name is not None:
                return name
            frame = frame.f_back
        return "other"

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        start = time.perf_counter()
        out = func(*args, **kwargs)
        seconds = time.perf_counter() - start
        phase = self.phases[self._phase()]
        phase.seconds += seconds
        phase.operations += 1
        view = any(r.alias_info is not None and not r.alias_info.is_write for r in func._schema.returns)
        if not view:  # a view moves nothing
            phase.bytes += operation_bytes(func, args, kwargs, out)
            phase.flops += operation_flops(func, args, kwargs, out)
        return out


def measure_peaks(device: str = "cpu", repeats: int = 5) -> Peaks:
    """The best of `repeats` float64 1024^2 matmuls (GFLOP/s) and 128 MiB copies (GB/s)."""
    n = 1024
    a = torch.randn(n, n, dtype=torch.float64, device=device)
    b = torch.randn(n, n, dtype=torch.float64, device=device)
    src = torch.empty(16 * 2 ** 20, dtype=torch.float64, device=device).fill_(1.0)  # 128 MiB
    dst = torch.empty_like(src)
    best_mm = best_copy = math.inf
    for _ in range(repeats + 1):  # the first of each warms up
        best_mm = min(best_mm, _timed(lambda: torch.mm(a, b), device))
        best_copy = min(best_copy, _timed(lambda: dst.copy_(src), device))
    return Peaks(2 * n ** 3 / best_mm / 1e9, 2 * src.numel() * src.element_size() / best_copy / 1e9)


def _timed(call, device: str) -> float:
    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
    sync()
    start = time.perf_counter()
    call()
    sync()
    return time.perf_counter() - start


def profile(name: str, batch: int, device: str = "cpu", dtype=torch.float64, steps: int = 5, warmup: int = 5,
            peaks: Peaks | None = None) -> Profile:
    """`steps` tracker steps of `batch` subjects, timed plainly and then through the counter."""
    from .bench import prepared_tracker

    tracker, sequence = prepared_tracker(name, batch, device, dtype, warmup + 2 * steps, warmup)
    sync = torch.cuda.synchronize if torch.device(device).type == "cuda" else (lambda: None)
    sync()
    start = time.perf_counter()
    for k in range(warmup, warmup + steps):
        tracker.step(sequence[k])
    sync()
    wall = time.perf_counter() - start
    counter = _Counter(phase_functions())
    with counter:
        for k in range(warmup + steps, warmup + 2 * steps):
            tracker.step(sequence[k])
    sync()
    phases = [counter.phases[p] for p in ORDER if p in counter.phases]
    for p in ORDER:
        if p in counter.phases:
            counter.phases[p].name = p
    return Profile(name, batch, str(dtype).removeprefix("torch."), steps, wall,
                   peaks if peaks is not None else measure_peaks(device), phases)


def table(result: Profile) -> str:
    """The roofline table of one profile: per phase and step, per subject, and against the peaks."""
    steps, B, peaks = result.steps, result.batch, result.peaks
    lines = [f"{result.model} B={B} {result.dtype}: {1e3 * result.wall_seconds / steps:.2f} ms/step wall without the "
             f"profiler; peaks {peaks.gflops:.1f} GFLOP/s (float64 matmul), {peaks.gbytes:.1f} GB/s (copy)",
             f"{'phase':22s} {'ops':>5s} {'ms/step':>8s} {'us/subj':>8s} {'time':>6s} {'flop/subj':>10s} {'B/subj':>9s} "
             f"{'flop/B':>7s} {'GFLOP/s':>8s} {'GB/s':>7s} {'roofline':>8s}"]
    operations = sum(p.seconds for p in result.phases)
    for p in [*result.phases, Phase("all operations", operations, sum(p.flops for p in result.phases),
                                    sum(p.bytes for p in result.phases), sum(p.operations for p in result.phases))]:
        seconds = max(p.seconds, 1e-12)
        intensity = p.flops / max(p.bytes, 1.0)
        bound = min(peaks.gflops, intensity * peaks.gbytes)  # GFLOP/s this phase could reach
        rate = p.flops / seconds / 1e9
        lines.append(f"{p.name:22s} {p.operations / steps:>5.0f} {1e3 * p.seconds / steps:>8.2f} "
                     f"{1e6 * p.seconds / steps / B:>8.2f} "
                     f"{p.seconds / max(operations, 1e-12):>6.1%} {p.flops / steps / B:>10,.0f} "
                     f"{p.bytes / steps / B:>9,.0f} {intensity:>7.2f} {rate:>8.2f} "
                     f"{p.bytes / seconds / 1e9:>7.2f} {(rate / bound if bound > 0 else 0.0):>8.1%}")
    return "\n".join(lines)
