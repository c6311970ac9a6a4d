"""The mailbox between the receiver and the live loop, and the loop's catching up
(torchik/pipelines/live/mailbox.py): a burst of samples is taken oldest first, none skipped, while
the loop keeps them all; keeping fewer steps to the newest and counts the others; without a
backlog given the loop keeps them all while its steps take at most half a frame, and from its
first steps on; a backlog given is kept whole."""

from __future__ import annotations

import numpy as np

from torchik.live.sample import BACKLOG, Sample
from torchik.pipelines.live import CatchUp, Mailbox
from torchik.pipelines.live.mailbox import EVIDENCE, RECENT


def burst(mailbox: Mailbox, frames: int, characters=(0, 3)) -> None:
    """`frames` samples of each character put at once, frame by frame."""
    for k in range(frames):
        for c in characters:
            mailbox.put(Sample(c, k, k / 100, 0.0, ("a",), np.array([[1.0, 0.0, 0.0, 0.0]]), None, None, None))


def taken(mailbox: Mailbox, keep: int) -> list[dict[int, int]]:
    """The frames of every take until the mailbox is empty, per character, and what each take says was skipped."""
    out = []
    while any(mailbox.queues.values()):
        got = mailbox.take((0, 3), timeout=0.0, gather=0.0, keep=keep)
        out.append(({c: s.frame for c, s in got.items()}, dict(mailbox.last_skips)))
    return out


def test_a_burst_kept_whole_is_taken_oldest_first_and_nothing_is_skipped():
    mailbox = Mailbox(backlog=8)
    burst(mailbox, 5)
    assert taken(mailbox, keep=8) == [({0: k, 3: k}, {0: 0, 3: 0}) for k in range(5)]
    assert mailbox.skipped == {}


def test_keeping_one_steps_to_the_newest_and_counts_the_others_once():
    mailbox = Mailbox(backlog=8)
    burst(mailbox, 5)
    assert taken(mailbox, keep=1) == [({0: 4, 3: 4}, {0: 4, 3: 4})]
    assert mailbox.skipped == {0: 4, 3: 4}


def test_a_burst_longer_than_the_backlog_loses_its_oldest_samples():
    mailbox = Mailbox(backlog=3)
    burst(mailbox, 5)
    assert taken(mailbox, keep=3) == [({0: 2, 3: 2}, {0: 2, 3: 2}), ({0: 3, 3: 3}, {0: 0, 3: 0}),
                                      ({0: 4, 3: 4}, {0: 0, 3: 0})]
    assert mailbox.skipped == {0: 2, 3: 2}


def test_the_loop_catches_up_while_its_median_step_takes_at_most_half_a_frame():
    rate, backlog = 240.0, 4
    half = 0.5 / rate
    fast, slow, given = CatchUp(), CatchUp(), CatchUp(backlog)
    for k in range(RECENT):
        fast.record(half * (50.0 if k % 4 == 0 else 0.9))  # a slow step now and then: still catching up
        slow.record(half * 1.1)
        given.record(half * 1.1)
    assert fast.keep(rate) == BACKLOG and slow.keep(rate) == 1
    assert given.keep(rate) == backlog  # a backlog given is kept whole, however slow the loop


def test_the_first_steps_which_carry_the_set_up_do_not_make_the_loop_step_over_samples():
    catch_up = CatchUp()
    for _ in range(EVIDENCE - 1):
        catch_up.record(1.0)  # set-up, a compiled step's capture
    assert catch_up.keep(240.0) == BACKLOG
    catch_up.record(1.0)
    assert catch_up.keep(240.0) == 1
