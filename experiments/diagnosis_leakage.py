"""How optimistic the held-out score was when the fits low-passed the whole series before the split.

    python experiments/diagnosis_leakage.py [--recordings 6] [--duration 12]

On clean recordings of experiments/diagnosis_study.py (pinocchio, Human48, white, AR(1) and 1/f
noise in turn), every candidate of the families whose fits low-pass (gyro bias, scale and stream
delay, heading drift, the position offset) is scored three ways: the series low-passed whole and no
guard between train and test blocks (the first version), low-passed whole with the 0.2 s guard (the
version before this one), and low-passed within each block with the guard (now). On clean data a
score is noise: the table gives its mean, its 95th percentile, its largest value, and how many
candidates pass the threshold of significance.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

KINDS = ("gyro_bias", "gyro_scale", "stream_delay", "heading_drift", "position_offset")


def scores(analysis, urdf: str, whole: bool, guard: float | None) -> list[float]:
    from torchik.pipelines.diagnosis import gyro, placement, position
    from torchik.pipelines.diagnosis.candidates import candidates
    from torchik.pipelines.diagnosis.effect import halves, lowpass_blocks
    from torchik.pipelines.diagnosis.series import lowpass

    filtered = (lambda x, time, cutoff, train, test: lowpass(x, time, cutoff)) if whole else lowpass_blocks
    for module in (gyro, placement, position):
        module.lowpass_blocks = filtered  # type: ignore[attr-defined]
    try:
        out = []
        for b in range(analysis.batch):
            train, test = halves(analysis.time, guard=guard)
            out += [c.score for c in candidates(analysis, b, train, test, urdf, KINDS) if c.fit is not None]
        return out
    finally:
        for module in (gyro, placement, position):
            module.lowpass_blocks = lowpass_blocks  # type: ignore[attr-defined]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--recordings", type=int, default=6, help="clean recordings (default 6)")
    parser.add_argument("--duration", type=float, default=12.0, help="seconds each (default 12)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    import diagnosis_study as study

    from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
    from torchik.pipelines.diagnosis.analysis import analyse
    from torchik.pipelines.diagnosis.effect import SIGNIFICANT

    links = list(TRACKED_LINKS["human48"])
    urdf, model = human_urdf(48), load_model("human48")
    recordings = [study.generate(study.Case(args.seed * 10000 + 9000 + k, (), study.NOISES[k % 3]), links,
                                 args.duration, 50.0)[0] for k in range(args.recordings)]
    analysis = analyse(model, recordings, links)
    print("| low-pass | guard | candidates | mean score | 95th percentile | largest | above the threshold |")
    print("|---|---|---|---|---|---|---|")
    for name, whole, guard in (("whole series", True, 0.0), ("whole series", True, None), ("within blocks", False, None)):
        s = np.array(scores(analysis, urdf, whole, guard))
        print(f"| {name} | {'0.2 s' if guard is None else 'none'} | {len(s)} | {s.mean():.1f} | "
              f"{np.percentile(s, 95):.1f} | {s.max():.1f} | {int((s > SIGNIFICANT).sum())} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
