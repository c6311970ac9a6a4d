"""The paper's tracker, the same to the bit across two checkouts: track fixed sequences with the
torchik on the path and save the trajectories; compare two saved runs.

    PYTHONPATH=/path/to/old/checkout python experiments/same_results.py --save old.npz
    python experiments/same_results.py --save new.npz
    python experiments/same_results.py --compare old.npz new.npz

Cases: Human66, one subject, PIQP; Human48, 128 subjects, the batched backend on the joints' tree;
iCub (coupled limits as rows), four subjects batched and one on PIQP. Each tracks 1 s at 100 Hz of
`periodic_motion` at 2 Hz (its own phases per subject). The comparison prints the largest difference
of the joint angles, base rotations and base positions per case.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

CASES = (("human66", 1, "piqp"), ("human48", 128, "batched"), ("icub", 4, "batched"), ("icub", 1, "piqp"))


def save(path: str) -> None:
    import torchik as tk
    from torchik.method.state import TargetSequence

    torch.set_num_threads(1)
    out = {}
    for name, B, backend in CASES:
        model, links = tk.load_model(name), tk.TRACKED_LINKS[name]
        parts = [tk.targets_from_motion(model, tk.periodic_motion(model, 1.0, 100, seed=i, frequency=2.0), links)
                 for i in range(B)]
        sequence = TargetSequence(parts[0].time, *(torch.cat([getattr(p, field) for p in parts], dim=1) for field in
                                                   ("position", "linear_velocity", "rotation", "angular_velocity")))
        run = tk.DynamicalIK(model, links, dt=0.01, backend=backend).run(sequence)
        for field in ("joint_positions", "base_rotation", "base_position"):
            out[f"{name} B={B} {backend}: {field}"] = getattr(run, field).numpy()
    np.savez(path, **out)
    print(f"saved {path} with {tk.__file__}")


def compare(a: str, b: str) -> None:
    first, second = np.load(a), np.load(b)
    for key in first.files:
        print(f"{key}: largest difference {np.abs(first[key] - second[key]).max():.3g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--save", metavar="NPZ")
    parser.add_argument("--compare", nargs=2, metavar="NPZ")
    args = parser.parse_args()
    if args.save:
        save(args.save)
    if args.compare:
        compare(*args.compare)


if __name__ == "__main__":
    main()
