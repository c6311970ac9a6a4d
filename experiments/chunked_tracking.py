"""The diagnosis' tracking in chunks (torchik/pipelines/diagnosis/chunks.py) against the run in one
piece: wall time of each, alternated, and how far apart their states are.

    python experiments/chunked_tracking.py RECORDING.npz [...] [--model human48] [--batch 1 4] [--repeats 5]

For every recording and batch size B (the recording B times, as the loop's variants are), tracks it
`--repeats` times each way, alternating (this machine's speed drifts by the minute), and prints
the fastest and median wall time of each, the chunks used, and the largest difference between the
two runs' states (base position and rotation, joints, velocities). For B = 1 the run in one piece
uses PIQP and the chunks the batched solver: their difference is the solvers' (about 1e-7 on the
joints), not the chunks'; for B > 1 both use the batched solver.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from torchik.io import read
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.diagnosis import analysis, chunks

FIELDS = ("base_position", "base_rotation", "joint_positions", "velocity")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", nargs="+", help="recordings torchik reads, with the model's link names")
    parser.add_argument("--model", default="human48")
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(1)  # as `torchik diagnose` tracks
    model = load_model(args.model)
    print("| recording | B | chunks x steps (warm-up) | in one piece, s (min / median) | in chunks, s "
          "| largest difference |")
    print("|---|---|---|---|---|---|")
    for path in args.recordings:
        recording = read(path)
        links = [name for name in TRACKED_LINKS[args.model] if name in recording.links]
        dt = float(np.median(np.diff(recording.time)))
        for B in args.batch:
            recordings = [recording] * B
            sequence = analysis.sequence_of(recordings, links, model.dtype)
            split = chunks.plan(len(sequence), B, dt, analysis.DEFAULT_GAIN,
                                bool(analysis.nominal_steps(sequence.time, dt).all()))
            whole_s, chunked_s = [], []
            for _ in range(args.repeats):
                start = time.perf_counter()
                whole = analysis.settled_run(model, links, sequence, dt, analysis.DEFAULT_GAIN, False, 0.5)
                whole_s.append(time.perf_counter() - start)
                start = time.perf_counter()
                chunked = analysis.track(model, recordings, links)
                chunked_s.append(time.perf_counter() - start)
            gap = max(float((getattr(whole, f) - getattr(chunked, f)).abs().max()) for f in FIELDS)
            layout = "in one piece" if split is None else f"{split.count} x {split.length} ({split.warm_up})"
            print(f"| {path} | {B} | {layout} | {min(whole_s):.2f} / {statistics.median(whole_s):.2f} | "
                  f"{min(chunked_s):.2f} / {statistics.median(chunked_s):.2f} | {gap:.1e} |", flush=True)


if __name__ == "__main__":
    main()
