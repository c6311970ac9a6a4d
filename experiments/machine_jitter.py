"""This machine's own tail: a fixed torch workload of about one compiled step's length (0.3 ms),
timed one call at a time as `torchik bench` times its loops, on one thread.

The workload does the same arithmetic on the same data every call, so whatever spread its times
have is the machine's (the scheduler, the neighbours of a virtual machine, caches), not the
code's. Its p99 / median bounds what a p99 target can ask of a step of that length here: a step
whose p99 is 0.4 ms needs a median of 0.4 divided by that ratio.

    python experiments/machine_jitter.py [--calls 3000] [--runs 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def fixed_workload(a: torch.Tensor, rounds: int = 4) -> torch.Tensor:
    """Four 96 x 96 float64 products with a tanh between: about 0.3 ms on this 2-core machine."""
    x = a
    for _ in range(rounds):
        x = torch.tanh(x @ a * 1e-2)
    return x


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--calls", type=int, default=3000, help="timed calls per run (default 3000)")
    parser.add_argument("--runs", type=int, default=3, help="runs (default 3)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    a = torch.randn(96, 96, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    for _ in range(200):  # warm: allocator, caches
        fixed_workload(a)
    for run in range(args.runs):
        times = np.empty(args.calls)
        for k in range(args.calls):
            start = time.perf_counter()
            fixed_workload(a)
            times[k] = time.perf_counter() - start
        median, p99 = np.median(times) * 1e3, np.percentile(times, 99) * 1e3
        print(f"run {run + 1}: median {median:.3f} ms, p99 {p99:.3f} ms, p99 / median {p99 / median:.2f}, "
              f"max {times.max() * 1e3:.2f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
