"""Inverse dynamics captured once for a batch size and replayed compiled (`capture.py`).

`inverse_dynamics` runs some 400 tensor operations eagerly; each reads and writes its operands from
memory, and for a thousand configurations those intermediates (tens of MB) do not stay in the
caches. Captured, TorchInductor fuses them into a few loops: on a GPU, Triton kernels; on a CPU, C++
loops over `CHUNK` rows at a time, whose intermediates stay in the caches (the batch is cut into
chunks, the last one padded), which on this project's CPU is twice as fast per row as one capture of
the whole batch, and on one thread: a chunk's loops are too short to share, and OpenMP's threads
waiting on a busy machine cost more than they bring (docs/dynamics.md has the figures). The first
capture of a model and chunk on a machine compiles for a minute or two; later ones load
TorchInductor's cache in seconds.

    dynamics = CompiledInverseDynamics(model, batch=1024)   # compile_seconds: how long that took
    forces = dynamics(p_B, R_B, s, nu, nu_dot)               # [B,6+n], as inverse_dynamics(...).forces
"""

from __future__ import annotations

import time
from typing import Sequence

import torch

from ...errors import InputError
from ..capture import capture
from ..kinematics.model import KinematicModel
from .inverse import GRAVITY, inverse_dynamics

CHUNK = 64  # rows per compiled call on a CPU


class CompiledInverseDynamics:
    """`inverse_dynamics(model, ...).forces` for batches of `batch` rows, captured and compiled at
    construction (raises `CaptureError` where that cannot be done here: no C++ compiler, ...).

    wrench_links: the links external wrenches act on, when the calls give them ([B,L,6]); gravity as
    `inverse_dynamics` takes it; chunk: rows per compiled call (default: CHUNK on a CPU, the whole
    batch on a GPU)."""

    def __init__(self, model: KinematicModel, batch: int, wrench_links: Sequence[str] | None = None,
                 gravity: Sequence[float] | torch.Tensor = GRAVITY, chunk: int | None = None):
        if batch < 1:
            raise InputError(f"batch must be positive, got {batch}")
        if model.n_subjects != 1:
            raise InputError("a compiled inverse dynamics takes a model of one subject (stacked subjects: call "
                             "inverse_dynamics)")
        self.model, self.batch = model, batch
        self.links = None if wrench_links is None else tuple(wrench_links)
        default = CHUNK if model.device.type == "cpu" else batch
        self.chunk = min(batch, chunk or default)

        def forces(p, R, s, velocity, acceleration, *wrenches):
            return [inverse_dynamics(model, p, R, s, velocity, acceleration, wrenches[0] if wrenches else None,
                                     self.links, gravity).forces]

        p, R, s = model.zero_configuration(self.chunk)
        nu = torch.zeros(self.chunk, 6 + model.n_dof, dtype=model.dtype, device=model.device)
        examples = [p, R, s, nu, nu]
        if self.links is not None:
            model.select(self.links)  # compiled now, outside the trace: its indices are data
            examples.append(torch.zeros(self.chunk, len(self.links), 6, dtype=model.dtype, device=model.device))
        start = time.perf_counter()
        threads = torch.get_num_threads()
        if model.device.type == "cpu":  # a chunk's loops are too short to share between threads: one
            torch.set_num_threads(1)
        try:
            self._compiled = capture(forces, examples)
        finally:
            torch.set_num_threads(threads)
        self.compile_seconds = time.perf_counter() - start

    def __call__(self, base_position: torch.Tensor, base_rotation: torch.Tensor, joint_positions: torch.Tensor,
                 velocity: torch.Tensor, acceleration: torch.Tensor,
                 external_wrenches: torch.Tensor | None = None) -> torch.Tensor:
        """forces [B,6+n] of `batch` configurations, as `inverse_dynamics(...).forces` gives them."""
        inputs = [base_position, base_rotation, joint_positions, velocity, acceleration]
        if (external_wrenches is None) != (self.links is None):
            raise InputError("external_wrenches must be given exactly when the dynamics was compiled with wrench_links")
        if external_wrenches is not None:
            inputs.append(external_wrenches)
        if base_position.shape[0] != self.batch:
            raise InputError(f"compiled for {self.batch} rows, given {base_position.shape[0]}")
        if self.chunk == self.batch:
            return self._compiled(*inputs)[0]
        out = velocity.new_empty(self.batch, 6 + self.model.n_dof)
        for start in range(0, self.batch, self.chunk):
            rows = [x[start:start + self.chunk] for x in inputs]
            short = self.chunk - rows[0].shape[0]
            if short:  # the last chunk, padded with copies of its first row
                rows = [torch.cat((x, x[:1].expand(short, *x.shape[1:]))) for x in rows]
            out[start:start + self.chunk] = self._compiled(*rows)[0][:self.chunk - short]
        return out
