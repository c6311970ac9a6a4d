"""scenarios: built-in motions with ground truth are self-consistent, respect the limits, and the tracker follows them;
made a chunk at a time, they are the same samples however they are cut."""

from unittest import mock

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchik import InputError
from torchik.io import angular_velocity_from_orientations
from torchik.io.targets import recording_targets
from torchik.method import so3
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.tracker import DynamicalIK
from torchik.synthetic import scenarios
from torchik.synthetic.scenarios import SCENARIOS, ScenarioSource, scenario

MODELS = {name: load_model(name) for name in ("human66", "human48", "icub")}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_orientations_and_angular_velocities_are_consistent(name):
    """The central difference of the orientations tends to the given angular velocity at second order."""
    model, links = MODELS["human48"], TRACKED_LINKS["human48"]
    gaps = []
    for rate in (200.0, 400.0):
        rec = scenario(name, model, links, duration=2.0, rate=rate)
        estimate = angular_velocity_from_orientations(rec.orientation, rec.time)
        gaps.append(np.abs(estimate - rec.angular_velocity)[1:-1].max())
    assert gaps[1] < 2e-3
    assert gaps[1] < 1e-12 or 3.5 < gaps[0] / gaps[1] < 4.5


@pytest.mark.parametrize("model_name", list(MODELS))
@pytest.mark.parametrize("name,bound", [("tpose", 1e-6), ("walking", 1e-6), ("running", 1e-5)])
def test_the_tracker_follows_each_scenario_on_its_model(model_name, name, bound):
    model, links = MODELS[model_name], TRACKED_LINKS[model_name]
    rec = scenario(name, model, links, duration=4.0, rate=100.0)
    tracker = DynamicalIK(model, links, position_gain=20.0, orientation_gain=20.0, dt=0.01)
    trajectory = tracker.run(recording_targets(rec, links))
    assert float(trajectory.diagnostics["mnte"][200:].max()) < bound  # after the transient from the zero configuration


@pytest.mark.parametrize("model_name", list(MODELS))
def test_scenarios_respect_joint_and_coupled_limits(model_name):
    model = MODELS[model_name]
    for name in SCENARIOS:
        s = torch.from_numpy(scenario(name, model, TRACKED_LINKS[model_name], duration=3.0).joint_positions)
        assert bool((s >= model.lower).all() and (s <= model.upper).all())
        if model.linear_limits is not None:
            assert bool((s @ model.linear_limits.A.T <= model.linear_limits.b).all())


def test_speeds_determinism_and_seeded_noise():
    model, links = MODELS["human66"], TRACKED_LINKS["human66"]
    walk = scenario("walking", model, links, duration=2.0)
    run = scenario("running", model, links, duration=2.0)
    assert np.isclose(walk.base_linear_velocity[:, 0].mean(), 4 / 3.6)
    assert np.isclose(run.base_linear_velocity[:, 0].mean(), 10 / 3.6)
    again = scenario("walking", model, links, duration=2.0)
    assert np.array_equal(walk.orientation, again.orientation)
    noisy = scenario("walking", model, links, duration=2.0, orientation_noise=0.01, gyro_noise=0.05, seed=3)
    noisy_again = scenario("walking", model, links, duration=2.0, orientation_noise=0.01, gyro_noise=0.05, seed=3)
    assert np.array_equal(noisy.angular_velocity, noisy_again.angular_velocity)
    clean = scenario("walking", model, links, duration=2.0, seed=3)  # the seed also sets the motion's phases
    assert 0.045 < np.std(noisy.angular_velocity - clean.angular_velocity) < 0.055


def test_unknown_scenarios_and_missing_links_are_refused():
    with pytest.raises(InputError, match="valid: tpose, walking, running"):
        scenario("dancing", MODELS["human66"], ["Pelvis"])
    rec = scenario("tpose", MODELS["human66"], ["Pelvis", "Head"], duration=0.5)
    with pytest.raises(InputError, match=r"the recording has no \['T8'\]"):
        recording_targets(rec, ["Pelvis", "T8"])


FIELDS = ("time", "orientation", "angular_velocity", "base_position", "base_linear_velocity", "joint_positions")


@settings(max_examples=25, deadline=None)
@given(name=st.sampled_from(list(SCENARIOS)), model_name=st.sampled_from(["human48", "icub"]),
       frames=st.integers(1, 120), rate=st.sampled_from([25.0, 100.0, 400.0]), seed=st.integers(0, 9),
       noise=st.sampled_from([(0.0, 0.0), (0.02, 0.0), (0.0, 0.1), (0.02, 0.1)]), size=st.integers(1, 50),
       whole_chunk=st.integers(1, 64), batch=st.integers(1, 40), links=st.integers(1, 3))
def test_chunks_of_any_size_are_the_whole_scenario(name, model_name, frames, rate, seed, noise, size, whole_chunk,
                                                   batch, links):
    """A ScenarioSource's chunks, concatenated, are the whole recording `scenario` gives (made in chunks of
    another size, the kinematics in batches of another size), noise included; each chunk has at most
    `size` frames and says where it starts."""
    model = MODELS[model_name]
    tracked = TRACKED_LINKS[model_name][:links] if links < 3 else TRACKED_LINKS[model_name]  # 1 and 2 links: few draws
    args = (name, model, tracked, (frames - 0.75) / rate, rate, seed, *noise)
    parts = list(ScenarioSource(*args).chunks(size))
    with mock.patch.object(scenarios, "CHUNK", whole_chunk), mock.patch.object(scenarios, "KINEMATICS_BATCH", batch):
        whole = scenario(*args)
    assert len(whole.time) == frames and sum(len(p.time) for p in parts) == frames
    assert [p.first_frame for p in parts] == list(range(0, frames, size))
    assert all(len(p.time) <= size for p in parts)
    for field in FIELDS:
        np.testing.assert_allclose(np.concatenate([getattr(p, field) for p in parts]), getattr(whole, field),
                                   rtol=0, atol=1e-13, err_msg=field)


@settings(max_examples=8, deadline=None)
@given(name=st.sampled_from(list(SCENARIOS)), frames=st.integers(1, 60), seed=st.integers(0, 9),
       orientation_noise=st.sampled_from([0.0, 0.01]), gyro_noise=st.sampled_from([0.0, 0.05]),
       links=st.integers(1, 23), size=st.integers(1, 30))
def test_the_noise_is_torch_randn_of_the_whole_recording(name, frames, seed, orientation_noise, gyro_noise, links,
                                                         size):
    """However the scenario is cut, its noise is what it always was: one torch.randn of [T,n,3] for the
    orientations, then one for the angular velocities, from a generator seeded seed + 1."""
    model, tracked = MODELS["human66"], TRACKED_LINKS["human66"][:links]
    args = (name, model, tracked, (frames - 0.75) / 100.0, 100.0, seed)
    clean = scenario(*args)
    noisy = list(ScenarioSource(*args, orientation_noise, gyro_noise).chunks(size))
    g = torch.Generator().manual_seed(seed + 1)
    R, w = torch.from_numpy(clean.orientation), torch.from_numpy(clean.angular_velocity)
    if orientation_noise:
        R = so3.exp(orientation_noise * torch.randn(R.shape[:-1], generator=g, dtype=R.dtype)) @ R
    if gyro_noise:
        w = w + gyro_noise * torch.randn(w.shape, generator=g, dtype=w.dtype)
    np.testing.assert_allclose(np.concatenate([p.orientation for p in noisy]), R.numpy(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.concatenate([p.angular_velocity for p in noisy]), w.numpy(), rtol=0, atol=1e-14)


@settings(max_examples=40, deadline=None)
@given(size=st.integers(16, 5000), seed=st.integers(0, 2**32), block=st.integers(1, 64))
def test_randn_in_pieces_is_torch_randn(size, seed, block):
    """The noise streams' normals are torch.randn's (to an ulp or two) and leave the generator where it does."""
    g, reference = torch.Generator().manual_seed(seed), torch.Generator().manual_seed(seed)
    pieces = list(scenarios._randn(g, size, block=16 * block))
    assert all(len(piece) <= 16 * block for piece in pieces)
    expected = torch.randn(size, generator=reference, dtype=torch.float64)
    torch.testing.assert_close(torch.cat(pieces), expected, rtol=0, atol=4 * 2.0**-52 * 8)  # |x| < 8 for these sizes
    assert torch.equal(torch.rand(4, generator=g, dtype=torch.float64),
                       torch.rand(4, generator=reference, dtype=torch.float64))


def test_a_long_scenario_is_made_a_chunk_at_a_time():
    """An hour's source holds its time stamps only (made at once: no sample is made before it is asked
    for); its chunks come in order, `size` frames each."""
    source = ScenarioSource("walking", MODELS["human66"], TRACKED_LINKS["human66"], duration=3600.0, rate=100.0)
    assert source.frames == 360_001 and source.time[-1] == 3600.0
    size, seen = 500, 0
    for part in source.chunks(size):
        assert part.first_frame == seen and len(part.time) == size and part.orientation.shape == (size, 23, 3, 3)
        seen += len(part.time)
        if seen >= 3 * size:  # the rest alike: an hour would take minutes
            break
