"""Time-parallel tracking (diagnosis/chunks.py): a recording tracked in overlapping chunks as one
batch gives the run in one piece's states, and where the chunks disagree, the run in one piece (and
the subject's later runs are not cut again)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.so3 import exp
from torchik.pipelines.diagnosis import analysis, chunks
from torchik.synthetic.scenarios import scenario

LINKS = TRACKED_LINKS["human48"]
FIELDS = ("base_position", "base_rotation", "joint_positions", "velocity")


@pytest.fixture(scope="module")
def walks(one_thread):
    """Two 8 s Human48 walks at 50 Hz with noise, the second with its left forearm's sensor turned by
    25 deg (a residual the joints cannot take up, which the tracker carries the whole run)."""
    model = load_model("human48")
    walks = [scenario("walking", model, LINKS, 8.0, 50.0, seed=s, orientation_noise=0.005, gyro_noise=0.02)
             for s in (3, 4)]
    turned = walks[1].orientation.copy()
    i = walks[1].links.index("LeftForeArm")
    turned[:, i] = turned[:, i] @ exp(torch.tensor([0.3, 0.3, 0.1], dtype=torch.float64)).numpy()
    return model, [walks[0], dataclasses.replace(walks[1], orientation=turned)]


def _one_piece(model, recordings):
    sequence = analysis.sequence_of(recordings, LINKS, model.dtype)
    dt = float(np.median(np.diff(recordings[0].time)))
    return analysis.settled_run(model, LINKS, sequence, dt, analysis.DEFAULT_GAIN, False, 0.5)


def test_a_run_in_chunks_has_the_states_of_the_run_in_one_piece(walks):
    """Two subjects (so that both runs use the batched solver) in six chunks: the states within 1e-9
    (the velocities within the gain times that)."""
    model, recordings = walks
    split = chunks.plan(len(recordings[0].time), 2, 0.02, analysis.DEFAULT_GAIN, True)
    assert split is not None and split.count == 6  # 400 samples, 55 warm-up steps: at most 400 // 55 - 1
    chunked, whole = analysis.track(model, recordings, LINKS), _one_piece(model, recordings)
    assert torch.equal(chunked.time, whole.time)
    for name in FIELDS:
        a, b = getattr(chunked, name), getattr(whole, name)
        assert a.shape == b.shape
        scale = analysis.DEFAULT_GAIN if name == "velocity" else 1.0
        assert float((a - b).abs().max()) < 1e-9 * scale, name
    for name, x in whole.diagnostics.items():
        assert chunked.diagnostics[name].shape == x.shape, name
    assert torch.equal(chunked.diagnostics["solved"], whole.diagnostics["solved"])


def test_in_float32_the_chunks_hand_over_within_its_rounding(walks):
    """float32 runs differ by a few units of the last place wherever they are cut: the hand-over
    allows ROUNDINGS of them, and the chunks are kept, within that of the run in one piece."""
    _, recordings = walks
    model = load_model("human48", dtype=torch.float32)
    chunked, whole = analysis.track(model, recordings, LINKS), _one_piece(model, recordings)
    tolerance = chunks.ROUNDINGS * torch.finfo(torch.float32).eps
    for name in FIELDS:
        a, b = getattr(chunked, name), getattr(whole, name)
        assert a.dtype == torch.float32
        scale = analysis.DEFAULT_GAIN if name == "velocity" else 1.0
        assert float((a - b).abs().max()) < tolerance * scale, name
    sequence = analysis.sequence_of(recordings, LINKS, torch.float32)
    split = chunks.plan(len(sequence), 2, 0.02, analysis.DEFAULT_GAIN, True)
    run = analysis.settled_run(model, LINKS, split.batch(sequence), 0.02, analysis.DEFAULT_GAIN, False, 0.5)
    assert split.stitch(run, sequence.time, analysis.DEFAULT_GAIN) is not None


def test_chunks_that_disagree_where_one_hands_over_give_the_run_in_one_piece(walks, monkeypatch):
    """With a warm-up of three steps the chunks have not forgotten their start: the hand-over check
    refuses them, and track returns the run in one piece, exactly."""
    model, recordings = walks
    monkeypatch.setattr(chunks, "FORGET", 0.3)
    monkeypatch.setattr(chunks, "FEWEST", 1)
    split = chunks.plan(len(recordings[0].time), 2, 0.02, analysis.DEFAULT_GAIN, True)
    assert split is not None and split.warm_up == 3
    sequence = analysis.sequence_of(recordings, LINKS, model.dtype)
    run = analysis.settled_run(model, LINKS, split.batch(sequence), 0.02, analysis.DEFAULT_GAIN, False, 0.5)
    assert split.stitch(run, sequence.time, analysis.DEFAULT_GAIN) is None
    chunked, whole = analysis.track(model, recordings, LINKS), _one_piece(model, recordings)
    for name in FIELDS:
        assert torch.equal(getattr(chunked, name), getattr(whole, name)), name


def test_once_its_chunks_disagree_a_subject_is_tracked_in_one_piece(walks, monkeypatch):
    """A Chunking turned off by chunks that disagreed keeps the later runs from trying again (each try
    costs half a run where the tracker does not forget its start); a fresh one tries."""
    model, recordings = walks
    monkeypatch.setattr(chunks, "FORGET", 0.3)
    monkeypatch.setattr(chunks, "FEWEST", 1)
    runs, settled_run = [], analysis.settled_run
    monkeypatch.setattr(analysis, "settled_run", lambda model, links, sequence, *rest: runs.append(
        sequence.rotation.shape[1]) or settled_run(model, links, sequence, *rest))
    split = chunks.plan(len(recordings[0].time), 2, 0.02, analysis.DEFAULT_GAIN, True)
    assert split is not None
    chunking = chunks.Chunking()
    analysis.track(model, recordings, LINKS, chunking=chunking)
    assert runs == [2 * split.count, 2] and not chunking.on  # the chunks of both subjects, then the two in one piece
    analysis.track(model, recordings, LINKS, chunking=chunking)
    assert runs[2:] == [2]
    analysis.track(model, recordings, LINKS, chunking=chunks.Chunking())
    assert runs[3:] == [2 * split.count, 2]


@pytest.mark.parametrize("steps", [100, 400, 601, 1200, 7200])
@pytest.mark.parametrize("subjects", [1, 3, 7])
@pytest.mark.parametrize("rate", [20.0, 25.0, 50.0, 120.0, 240.0])
def test_the_chunks_tile_the_recording_each_after_its_warm_up(steps, subjects, rate):
    """Every sample is owned by one chunk, which tracked it after at least its warm-up, and keeps
    at least as many as it warms up on; the warm-up leaves FORGET of the start (at least FEWEST steps:
    at 20 Hz, K dt = 1 and the linear decay would say one)."""
    split = chunks.plan(steps, subjects, 1 / rate, 20.0, True)
    decay = abs(1 - 20.0 / rate)
    warm_up = max(chunks.FEWEST, int(np.ceil(np.log(chunks.FORGET) / np.log(decay))) if decay > 0 else 1)
    if split is None:
        assert steps < 3 * warm_up or subjects * 2 > chunks.BATCH or decay >= chunks.SLOWEST
        return
    assert split.warm_up == warm_up and (decay == 0 or decay ** warm_up <= chunks.FORGET)
    assert split.owned[0] == 0 and split.owned[-1] == steps and split.starts[0] == 0
    assert 2 <= split.count and split.count * subjects <= chunks.BATCH + subjects - 1
    for c, start in enumerate(split.starts):
        assert 0 <= start and start + split.length <= steps
        assert split.owned[c + 1] - split.owned[c] >= split.warm_up  # as many as it warms up on
        assert split.owned[c + 1] <= start + split.length  # it tracked what it owns
        if c:
            assert split.owned[c] - start == split.warm_up  # after its warm-up
            assert split.owned[c] <= split.starts[c - 1] + split.length  # the one before it tracked the hand-over


def test_a_recording_sampled_unevenly_or_too_fast_for_the_gain_is_tracked_in_one_piece():
    assert chunks.plan(1200, 1, 0.01, 20.0, nominal=False) is None  # a step of its own dt
    assert chunks.plan(1200, 1, 0.1, 20.0, True) is None  # K dt = 2: |1 - K dt| = 1, nothing decays
    assert chunks.plan(1200, chunks.BATCH, 0.01, 20.0, True) is None  # the batch is large enough


def test_a_batch_whose_chunks_disagree_turns_off_its_subjects_and_no_others(walks, monkeypatch):
    """analyse_subjects tracks a model's subjects as one batch: in chunks only if every one of them
    still may be, and a batch whose chunks disagree turns off its own subjects, not those it did
    not try."""
    from torchik.pipelines.diagnosis.subject import Subject, analyse_subjects

    model, recordings = walks
    other = load_model("human48")  # another model: a batch of its own
    kept = Subject(recordings[0], "", model)
    refused = Subject(recordings[1], "", model, chunking=chunks.Chunking(False))
    tried = Subject(recordings[1], "", other)
    monkeypatch.setattr(chunks, "FORGET", 0.3)
    monkeypatch.setattr(chunks, "FEWEST", 1)
    analyse_subjects([kept, refused, tried], LINKS, analysis.DEFAULT_GAIN, False, 20)
    assert kept.chunking.on and not refused.chunking.on and not tried.chunking.on
    monkeypatch.undo()
    analyse_subjects([kept], LINKS, analysis.DEFAULT_GAIN, False, 20)  # now its chunks agree
    assert kept.chunking.on
