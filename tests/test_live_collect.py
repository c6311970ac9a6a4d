"""The live loop's garbage collection (torchik/pipelines/live/collect.py): automatic collection
is off while it runs and as before after; `collect()` runs a collection exactly when the
collector's own thresholds make one due, the oldest generation due."""

from __future__ import annotations

import gc
import weakref

import pytest

from torchik.pipelines.live.collect import IdleCollector


@pytest.fixture
def thresholds():
    saved = gc.get_threshold()
    yield
    gc.set_threshold(*saved)


class _Node:
    pass


def _cycles(count: int) -> list[weakref.ref]:
    """`count` unreachable reference cycles (only a cyclic collection frees them); weak references to them."""
    refs = []
    for _ in range(count):
        node = _Node()
        node.itself = node  # type: ignore[attr-defined]
        refs.append(weakref.ref(node))
    return refs


@pytest.mark.parametrize("enabled", [True, False])
def test_automatic_collection_is_off_between_start_and_stop_and_as_before_after(enabled):
    was = gc.isenabled()
    (gc.enable if enabled else gc.disable)()
    try:
        collector = IdleCollector().start()
        assert not gc.isenabled()
        collector.stop()
        assert gc.isenabled() == enabled
    finally:
        (gc.enable if was else gc.disable)()


def test_a_collection_runs_only_when_the_thresholds_make_one_due_and_frees_the_cycles(thresholds):
    gc.set_threshold(500, 10, 10)
    collector = IdleCollector().start()
    try:
        gc.collect()
        assert collector.collect() is None  # nothing allocated since
        garbage = _cycles(1000)
        assert collector.collect() == 0
        assert gc.get_count()[0] < 500 and all(ref() is None for ref in garbage)
    finally:
        collector.stop()


def test_the_oldest_generation_due_is_collected(thresholds):
    gc.set_threshold(100, 2, 1000)
    collector = IdleCollector().start()
    try:
        gc.collect()
        generations = []
        for _ in range(8):
            _cycles(200)
            generations.append(collector.collect())
        # the count of gen-0 collections must exceed the threshold (2), as in CPython's own trigger
        assert generations == [0, 0, 0, 1, 0, 0, 0, 1]
    finally:
        collector.stop()
