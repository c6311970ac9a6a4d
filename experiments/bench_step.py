"""Subject-steps per second of the whole tracking step: torchik's batched step for Human66, Human48
and iCub at B = 1, 64, 1024, 8192 against per-subject loops (torchik + PIQP, pinocchio + daqp,
pinocchio + PIQP), as a table and JSON. The same as `torchik bench`; see torchik/bench.py.

    python experiments/bench_step.py [--batch 1 64 1024 8192] [--json bench.json] [--device cuda]
"""

import sys

from torchik.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
