"""What the package knows about itself: its version, and the files it reads at run time, shipped inside
it and found through importlib.resources so that a wheel has them as an editable checkout does
(`maps/`: the built-in link maps; the repository's top-level `models/maps` is a link to that folder:
one copy, shown in both places). The bottom layer: imports nothing of torchik."""

from __future__ import annotations

from importlib import metadata, resources
from importlib.resources.abc import Traversable


def version() -> str:
    """pyproject.toml's version as pip installed it (editable or from a wheel); "0+unknown" for a
    source tree that was never installed."""
    try:
        return metadata.version("torchik")
    except metadata.PackageNotFoundError:
        return "0+unknown"


def maps_folder() -> Traversable:
    """The built-in link maps' folder inside the installed package."""
    return resources.files(__name__) / "maps"
