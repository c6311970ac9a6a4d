"""The captured step against the eager one on the bench's walking motion: both trackers step the
same B subjects, and the largest difference of their states after the last step is printed; then
that of a second captured run from the same start (zero: the captured step is reproducible).

    python experiments/captured_agreement.py [--model human66] [--batch 1024] [--steps 60] [--device cuda] [--solvers]

With --solvers, the eager step's own two solves of the same run are compared too: on the joints'
tree (whatever the batch size) and dense. Their difference is
the rounding the model's QP amplifies (iCub's, damped by 1e-9 at its shoulders' gimbal locks, a
billionfold), the scale against which the captured step's difference is read.

The first capture of a model's step and batch size on a machine compiles for a minute or two.
"""

from __future__ import annotations

import argparse

from torchik.method.models import MODELS, TRACKED_LINKS, load_model
from torchik.method.structure import BatchSetup
from torchik.method.tracker import DynamicalIK
from torchik.pipelines import bench


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", default="human66", choices=MODELS)
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--solvers", action="store_true", help="also the eager step solved on the tree against dense")
    args = parser.parse_args()
    model, links = load_model(args.model, device=args.device), TRACKED_LINKS[args.model]
    motion = bench._motion(model, args.batch, args.steps)
    sequence = bench._targets(model, motion, links, args.device)
    start = type(motion.state(0))(*(x.to(args.device) for x in vars(motion.state(0)).values()))

    def final_state(compiled: bool):
        tracker = DynamicalIK(model, links, position_gain=bench.GAIN, orientation_gain=bench.GAIN, dt=1 / bench.RATE,
                              damping=bench.DAMPING, backend="batched", compile=compiled)
        tracker.reset(start, batch=args.batch)
        for k in range(args.steps):
            tracker.step(sequence[k])
        captured = tracker.captured
        if compiled and (captured is None or captured.unavailable):
            raise SystemExit("the step could not be captured here")
        return tracker.state

    def difference(a, b) -> str:
        pairs = zip(vars(a).items(), vars(b).values())
        return ", ".join(f"{name} {float((x - y).abs().max()):.2e}" for (name, x), y in pairs)

    eager, captured = final_state(False), final_state(True)
    print(f"{args.model}, B = {args.batch}, {args.steps} steps on {args.device}: the captured and eager states "
          f"differ by at most: {difference(captured, eager)}")
    print(f"the captured run again against the first: {difference(final_state(True), captured)}")
    if args.solvers:
        solved = {}
        usual = BatchSetup.TREE_FROM
        try:
            for form, tree_from in (("tree", 1), ("dense", args.batch + 1)):
                BatchSetup.TREE_FROM = tree_from
                solved[form] = final_state(False)
        finally:
            BatchSetup.TREE_FROM = usual
        print(f"the eager step on the tree against dense: {difference(solved['tree'], solved['dense'])}")


if __name__ == "__main__":
    main()
