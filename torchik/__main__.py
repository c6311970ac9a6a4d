"""`python -m torchik` runs the command line, as `torchik` does."""

import sys

from .cli import main

sys.exit(main())
