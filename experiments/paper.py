"""The paper's experiments: the same as `torchik experiment paper` (see torchik/pipelines/experiment/).

    python experiments/paper.py --out paper/ [--data FILE --map MAP] [--duration 10] ...
"""

import sys

from torchik.cli import main

if __name__ == "__main__":
    sys.exit(main(["experiment", "paper", *sys.argv[1:]]))
