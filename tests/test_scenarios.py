"""scenarios: built-in motions with ground truth are self-consistent, respect the limits, and the tracker follows them."""

import numpy as np
import pytest
import torch

from torchik import InputError
from torchik.io import angular_velocity_from_orientations
from torchik.io.targets import recording_targets
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.scenarios import SCENARIOS, scenario

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
