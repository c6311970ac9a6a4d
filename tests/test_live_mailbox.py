"""The mailbox between the receiver and the live loop, and the loop's catching up
(torchik/pipelines/live/mailbox.py): a burst of samples is taken oldest first, none skipped, while
the loop keeps them all; keeping fewer, a longer burst, or samples stepped over before step to the
newest and count the others; without a
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


def test_a_burst_longer_than_the_backlog_steps_to_the_newest_rather_than_staying_behind():
    mailbox = Mailbox(backlog=3)
    burst(mailbox, 5)
    assert taken(mailbox, keep=3) == [({0: 4, 3: 4}, {0: 4, 3: 4})]
    assert mailbox.skipped == {0: 4, 3: 4}


def test_a_character_whose_samples_the_receiver_stepped_over_steps_to_its_newest():
    mailbox = Mailbox(backlog=8)
    mailbox.count_skipped(0, 2)  # as a receiver process reports its own
    burst(mailbox, 3)
    assert taken(mailbox, keep=8) == [({0: 2, 3: 0}, {0: 4, 3: 0}), ({3: 1}, {3: 0}), ({3: 2}, {3: 0})]
    assert mailbox.skipped == {0: 4}


def sample(arrival: float) -> dict[int, Sample]:
    return {0: Sample(0, 0, 0.0, arrival, ("a",), np.array([[1.0, 0.0, 0.0, 0.0]]), None, None, None)}


def stepped(catch_up: CatchUp, steps: int, period: float, cost: float, behind: bool) -> None:
    """`steps` steps a `period` apart, each taking `cost` from the take to its end; the sample of each
    came just before the step began, or (behind) before the previous one ended."""
    for k in range(steps):
        start = k * period
        catch_up.record(sample(start - period if behind else start - 1e-6), start, start + cost)


def test_the_loop_catches_up_while_its_median_cost_of_a_sample_is_at_most_half_a_frame():
    rate, backlog = 240.0, 4
    half = 0.5 / rate
    fast, slow, given = CatchUp(), CatchUp(), CatchUp(backlog)
    stepped(fast, RECENT, 2 * half, 0.9 * half, behind=False)
    fast.record(sample(RECENT * 2 * half), RECENT * 2 * half, RECENT * 2 * half + 50 * half)  # a slow step now and then
    stepped(slow, RECENT, 2 * half, 1.1 * half, behind=False)
    stepped(given, RECENT, 2 * half, 1.1 * half, behind=False)
    assert fast.keep(rate) == BACKLOG and slow.keep(rate) == 1
    assert given.keep(rate) == backlog  # a backlog given is kept whole, however slow the loop


def test_a_loop_behind_its_samples_counts_the_whole_time_between_its_steps_not_only_the_steps():
    """Behind a burst, the loop's short steps come 1.1 half-frames apart (it lost its core between
    them): it catches up slower than its steps say, and steps to the newest."""
    rate = 240.0
    half = 0.5 / rate
    behind, waiting = CatchUp(), CatchUp()
    stepped(behind, RECENT, 1.1 * half, 0.2 * half, behind=True)
    stepped(waiting, RECENT, 2.2 * half, 0.2 * half, behind=False)  # the same steps, each waiting for its sample
    assert behind.keep(rate) == 1 and waiting.keep(rate) == BACKLOG


def test_the_first_steps_which_carry_the_set_up_do_not_make_the_loop_step_over_samples():
    catch_up = CatchUp()
    stepped(catch_up, EVIDENCE - 1, 1.0, 1.0, behind=False)  # set-up, a compiled step's capture
    assert catch_up.keep(240.0) == BACKLOG
    stepped(catch_up, 1, 1.0, 1.0, behind=False)
    assert catch_up.keep(240.0) == 1
