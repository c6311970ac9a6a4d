"""How much of a batched step its QP takes, eager and captured, on the bench's walking motion.

Both trackers step the same B subjects for the same steps (after the bench's warm-up); per step
the tracker's own timings are kept: the whole step and, where the backend ran, its QP. Printed per
tracker: the step's median, the steps whose QP the backend solved and their QP's median, and the
mean active-set iterations of those (the batch's most; a captured step's backend counts the captured
factorisation's guess, no bound held, as its first).

    python experiments/captured_qp_share.py [--model icub] [--batch 1024] [--steps 300] [--threads 2]

The first capture of a model's step and batch size on a machine compiles for a minute or two.
"""

from __future__ import annotations

import argparse
import math
import statistics

import torch

import torchik as tk
from torchik.method.models import MODELS
from torchik.pipelines.bench import prepared_tracker

WARMUP = 5


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="icub", choices=MODELS)
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    tk.keep_freed_memory()
    for compiled in (False, True):
        tracker, sequence = prepared_tracker(args.model, args.batch, "cpu", torch.float64, WARMUP + args.steps, WARMUP,
                                             compiled)
        steps, qp, iterations = [], [], []
        for k in range(WARMUP, WARMUP + args.steps):
            _, diagnostics = tracker.step(sequence[k])
            steps.append(diagnostics.step_time)
            if not math.isnan(diagnostics.qp_time):
                qp.append(diagnostics.qp_time)
                iterations.append(tracker.backend.iterations)
        qp_median = f"{1e3 * statistics.median(qp):.2f} ms" if qp else "-"
        mean_iterations = f"{sum(iterations) / len(iterations):.2f}" if iterations else "-"
        print(f"{args.model} B={args.batch} {'captured' if compiled else 'eager   '}: step median "
              f"{1e3 * statistics.median(steps):.2f} ms; QP solved by the backend in {len(qp)} of {len(steps)} "
              f"steps, median {qp_median}, {mean_iterations} iterations")


if __name__ == "__main__":
    main()
