"""Live sources: motion streams read as they arrive (Xsens MVN over UDP or TCP, Lab Streaming
Layer), each yielding `Sample`s, and the writers `torchik replay` uses to play a recording as such a
stream. Data I/O, as `torchik/io/` is: the live loop that tracks the samples is
`torchik/pipelines/live.py`."""

from .sample import Sample, SourceStats, parse_url
from .sources import open_source

__all__ = ["Sample", "SourceStats", "open_source", "parse_url"]
