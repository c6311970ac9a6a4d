"""The captured step against the eager one on the bench's walking motion: both trackers step the
same B subjects, and the largest difference of their states after the last step is printed.

    python experiments/captured_agreement.py [--model human66] [--batch 1024] [--steps 60] [--device cuda]

The first capture of a model's step and batch size on a machine compiles for a minute or two.
"""

from __future__ import annotations

import argparse

from torchik.method.models import MODELS, TRACKED_LINKS, load_model
from torchik.method.tracker import DynamicalIK
from torchik.pipelines import bench


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="human66", choices=MODELS)
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    model, links = load_model(args.model, device=args.device), TRACKED_LINKS[args.model]
    motion = bench._motion(model, args.batch, args.steps)
    sequence = bench._targets(model, motion, links, args.device)
    start = type(motion.state(0))(*(x.to(args.device) for x in vars(motion.state(0)).values()))
    states = {}
    for compiled in (False, True):
        tracker = DynamicalIK(model, links, position_gain=bench.GAIN, orientation_gain=bench.GAIN, dt=1 / bench.RATE,
                              damping=bench.DAMPING, backend="batched", compile=compiled)
        tracker.reset(start, batch=args.batch)
        for k in range(args.steps):
            tracker.step(sequence[k])
        captured = tracker.captured
        if compiled and (captured is None or captured.unavailable):
            raise SystemExit("the step could not be captured here")
        states[compiled] = tracker.state
    difference = max(float((a - b).abs().max()) for a, b in zip(vars(states[False]).values(), vars(states[True]).values()))
    print(f"{args.model}, B = {args.batch}, {args.steps} steps on {args.device}: the captured and eager states "
          f"differ by at most {difference:.2e}")


if __name__ == "__main__":
    main()
