"""`python -m torchik` runs the command line, as `torchik` does."""

from .cli import command

command()
