"""live targets (torchik/pipelines/live/targets.py): a step's targets from one sample per character
put each character's measurement in its own row, whichever characters sent one; a character without
a sample, or without a field, has those targets unknown (NaN: dropped by the tracker)."""

import numpy as np
import torch

from torchik.live.sample import Sample
from torchik.method import so3
from torchik.pipelines.live.targets import Selection, sample_targets

LINKS = ("Pelvis", "T8", "Head")


def _sample(character: int, seed: int, velocities: bool = True) -> Sample:
    g = np.random.default_rng(seed)
    q = g.normal(size=(len(LINKS), 4))
    field = (lambda: g.normal(size=(len(LINKS), 3))) if velocities else (lambda: None)
    return Sample(character, 0, 0.0, 0.0, LINKS, q, field(), field(), field())


def test_each_character_gets_its_own_rows_and_a_missing_one_is_unknown():
    selection = Selection.build(LINKS, ("T8", "Pelvis"))  # rows picked and reordered
    samples = [_sample(c, seed=c) for c in range(3)]
    every = sample_targets(samples, selection)
    some = sample_targets([samples[0], None, samples[2]], selection)
    for b in (0, 2):
        s = samples[b]
        expected = so3.quaternion_to_matrix(torch.from_numpy(s.quaternion / np.linalg.norm(s.quaternion, axis=-1,
                                                                                             keepdims=True)))
        assert torch.allclose(every.rotation[b], expected[[1, 0]], atol=1e-12)
        assert torch.equal(some.rotation[b], every.rotation[b])
        assert torch.equal(some.angular_velocity[b], torch.from_numpy(s.angular_velocity[[1, 0]]))
        assert torch.equal(some.position[b, 0], torch.from_numpy(s.position[1]))  # the base: the first link, T8
    assert bool(some.rotation[1].isnan().all()) and bool(some.angular_velocity[1].isnan().all())
    assert bool(some.position[1].isnan().all())


def test_a_field_one_character_lacks_is_unknown_for_it_alone():
    selection = Selection.build(LINKS, LINKS)
    with_field, without = _sample(0, seed=1), _sample(1, seed=2, velocities=False)
    targets = sample_targets([with_field, without], selection)
    assert torch.equal(targets.angular_velocity[0], torch.from_numpy(with_field.angular_velocity))
    assert bool(targets.angular_velocity[1].isnan().all())
    assert not bool(targets.rotation.isnan().any())
