"""Python's cyclic garbage collector run by the live loop between samples (`IdleCollector`).

Left to itself the collector runs whenever allocations cross its thresholds: in the middle of a
step, the targets' assembly or an LSL push, and that sample's latency takes the pause (the
timings: experiments/live_latency.md). The live loop turns automatic collection off and runs the
collections that have come due itself, after a step has been published, when the next sample is
the furthest off. The thresholds stay the collector's own: only the moment changes."""

from __future__ import annotations

import gc


class IdleCollector:
    """Between `start()` and `stop()` automatic collection is off (then as it was); `collect()`
    runs the oldest generation the collector would have collected by now, if any."""

    def __init__(self) -> None:
        self._was_enabled = False

    def start(self) -> "IdleCollector":
        self._was_enabled = gc.isenabled()
        gc.disable()
        return self

    def stop(self) -> None:
        if self._was_enabled:
            gc.enable()

    def collect(self) -> int | None:
        """Collect the oldest generation whose count exceeds its threshold (as CPython's own trigger
        does: allocations for generation 0, collections of the younger one for the others); the
        generation collected, or None when none was due."""
        count, threshold = gc.get_count(), gc.get_threshold()
        if not threshold[0] or count[0] <= threshold[0]:  # a threshold of 0 turns collection off
            return None
        generation = max(g for g in range(3) if count[g] > threshold[g])
        gc.collect(generation)
        return generation
