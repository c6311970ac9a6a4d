"""Capturing a function of tensors once and replaying it compiled.

`capture(fn, inputs)` traces `fn` on fake tensors of the inputs' shapes into one graph of tensor
operations (torch.fx's make_fx: Python runs once, its branches resolved for these shapes) and
compiles the graph with TorchInductor: on CPU into fused C++ loops called from a C++ wrapper, on
CUDA into Triton kernels. The result is a plain function of the same
tensors (same shapes, dtypes and devices) with no guards and no Python per operation: what a small
batch's step spends in dispatching some 180 operations becomes one call.

Products of small matrices (3x3 rotations, the [N,3] joint axes, the target mask) are expanded into
elementwise products and sums before compiling, so that they fuse with their neighbours instead of
each calling a BLAS routine, whose overhead for a 3x3 block is a thousand times its arithmetic.

The compiled code lands in TorchInductor's cache (a directory under the system's temporary one):
the first capture of a graph on a machine compiles C++ (tens of seconds), later ones, in any
process, load it (a few seconds of tracing and lookup).
"""

from __future__ import annotations

import contextlib
import logging
from typing import Any, Callable, Sequence

import torch

from ..errors import TorchikError

SMALL_CONTRACTION = 32  # matrix products contracting over at most this many terms are expanded elementwise
LARGEST_EXPANSION = 1 << 22  # ... unless the elementwise product would hold more numbers than this


_tracing = False


def tracing() -> bool:
    """Whether a function is being traced for capture now. Code that writes level by level into one
    buffer, the fastest form eagerly, makes a tensor per level instead while traced: in the
    captured graph every in-place write of a slice would copy the whole buffer."""
    return _tracing


class CaptureError(TorchikError):
    """The function could not be traced or compiled here (no C++ compiler, an operation TorchInductor
    cannot lower, ...): the message says why; the eager function still works."""


def capture(fn: Callable[..., Sequence[torch.Tensor]], inputs: Sequence[torch.Tensor]) -> Callable[..., list]:
    """fn traced for the shapes of `inputs` and compiled; returns a function of tensors like them
    that returns fn's outputs as a list. Raises CaptureError when that cannot be done here."""
    global _tracing
    try:
        from torch._inductor.compile_fx import compile_fx
        from torch.fx.experimental.proxy_tensor import make_fx

        examples = [t.clone() for t in inputs]  # ordinary tensors (inputs may be inference tensors)
        with torch.inference_mode(False), torch.no_grad():
            # fake tensors: shapes and dtypes only; the constants fn closes over stay real. The small
            # products are expanded here, in the trace: given to compile_fx, a decomposition table
            # would keep the graph out of TorchInductor's cache (it cannot hash one)
            _tracing = True
            try:
                graph = make_fx(fn, decomposition_table=_small_products(), tracing_mode="fake",
                                _allow_non_fake_inputs=True)(*examples)
            finally:
                _tracing = False
            # on CPU the C++ wrapper calls the kernels without Python between them, and products and
            # sums contract into fused multiply-adds (a little faster: experiments/speed_history.md;
            # the states move by 1e-13); on CUDA, Triton kernels launched one by
            # one: not a CUDA graph, whose outputs the next replay would overwrite while the tracker
            # still holds them (the state, two steps of targets)
            cpu = all(t.device.type == "cpu" for t in inputs)
            patches = {"cpp_wrapper": True, **_contraction()} if cpu else {}
            with _quiet_fallbacks():
                compiled: Any = compile_fx(graph, examples, config_patches=patches)
                compiled(*examples)  # the first call finishes the compilation
    except Exception as error:  # an environment without a compiler fails in many ways
        raise CaptureError(f"could not compile the step ({type(error).__name__}: {str(error).splitlines()[0]})") from error
    return compiled


def _contraction() -> dict:
    """The C++ compiler's license to fuse multiply-adds, asked for where this torch's option takes
    "fast" (a string, as in torch 2.13); elsewhere the compiler's default. An unknown key would fail
    the whole capture on an older torch, which pyproject allows."""
    from torch._inductor import config

    option = getattr(config.cpp, "enable_floating_point_contract_flag", None)
    return {"cpp.enable_floating_point_contract_flag": "fast"} if isinstance(option, str) else {}


class _NoShimNotice(logging.Filter):
    """Drops TorchInductor's notice that an operation (the Cholesky factorisation, the triangular
    solves) has no C shim: the C++ wrapper then calls it through the dispatcher, as the eager step
    does, which is no fault of the user's and nothing they can act on."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "missing a c-shim implementation" not in str(record.msg)


@contextlib.contextmanager
def _quiet_fallbacks():
    """TorchInductor's lowering without its no-C-shim notices (`_NoShimNotice`), its other messages kept."""
    logger, notice = logging.getLogger("torch._inductor.ir"), _NoShimNotice()
    logger.addFilter(notice)
    try:
        yield
    finally:
        logger.removeFilter(notice)


def _small_products() -> dict:
    """Decompositions of bmm, mm and baddbmm into elementwise products and a sum over the
    contracted dimension, where it is short (`SMALL_CONTRACTION`); NotImplemented keeps the others."""
    aten = torch.ops.aten

    def expanded(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor | None:
        if a.shape[-1] > SMALL_CONTRACTION or a.numel() * b.shape[-1] > LARGEST_EXPANSION:
            return None
        return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)

    def product(a, b):
        out = expanded(a, b)
        return NotImplemented if out is None else out

    def product_added(x, a, b, beta=1, alpha=1):
        out = expanded(a, b)
        if out is None:
            return NotImplemented
        return alpha * out if beta == 0 else beta * x + alpha * out  # beta 0 ignores x, NaN included

    return {aten.bmm.default: product, aten.mm.default: product, aten.baddbmm.default: product_added}
