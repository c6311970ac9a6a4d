"""io.recording: recordings round-trip exactly through .npz, and invalid ones are refused with the reason."""


import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from torchik.io import Recording, RecordingError, angular_velocity_from_orientations, load_recording, save_recording
from torchik.method import so3


@st.composite
def recordings(draw):
    T = draw(st.integers(1, 12))
    n = draw(st.integers(1, 5))
    links = draw(st.lists(st.text(st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")), min_size=1, max_size=8),
                          min_size=n, max_size=n, unique=True))
    seed = draw(st.integers(0, 2**31 - 1))
    g = np.random.default_rng(seed)
    steps = g.uniform(1e-4, 0.1, T)
    time = np.cumsum(steps) + draw(st.floats(-10, 10))
    R = so3.random_rotation((T, n), torch.Generator().manual_seed(seed)).numpy()
    w = g.normal(size=(T, n, 3))
    if draw(st.booleans()):  # a gap
        R[g.integers(T), g.integers(n)] = np.nan
    joints = draw(st.one_of(st.none(), st.integers(1, 4)))
    values = st.one_of(st.floats(allow_nan=False), st.integers(), st.text(max_size=6), st.lists(st.integers(), max_size=3))
    meta = draw(st.dictionaries(st.text(max_size=6), values, max_size=4))
    return Recording(time=time, links=tuple(links), orientation=R, angular_velocity=w, base_link=links[0],
                     base_position=g.normal(size=(T, 3)), base_linear_velocity=g.normal(size=(T, 3)),
                     joint_names=None if joints is None else tuple(f"j{i}" for i in range(joints)),
                     joint_positions=None if joints is None else g.normal(size=(T, joints)), meta=meta)


@settings(max_examples=60, deadline=None)
@given(recordings())
def test_writing_and_reading_round_trips_exactly(tmp_path_factory, rec):
    path = save_recording(rec, tmp_path_factory.mktemp("rec") / "r.npz")
    back = load_recording(path)
    for name in ("time", "orientation", "angular_velocity", "base_position", "base_linear_velocity"):
        assert np.array_equal(getattr(back, name), getattr(rec, name), equal_nan=True), name
    assert back.links == rec.links and back.base_link == rec.base_link and back.meta == rec.meta
    assert back.joint_names == rec.joint_names
    if rec.joint_positions is not None:
        assert np.array_equal(back.joint_positions, rec.joint_positions)


def valid(**changes):
    g = np.random.default_rng(0)
    base = dict(time=np.arange(4, dtype=np.float64) / 100, links=("Pelvis", "Head"),
                orientation=so3.random_rotation((4, 2), torch.Generator().manual_seed(0)).numpy(),
                angular_velocity=g.normal(size=(4, 2, 3)), base_link="Pelvis", base_position=g.normal(size=(4, 3)),
                base_linear_velocity=g.normal(size=(4, 3)))
    base.update(changes)
    return base


@pytest.mark.parametrize("change,message", [
    (dict(time=np.array([0.0, 0.01, 0.01, 0.03])), "strictly increasing: frame 2"),
    (dict(base_link="Tail"), "base_link 'Tail' is not one of the links"),
    (dict(orientation=np.ones((4, 2, 3, 3))), "orientation of 'Pelvis' at frame 0 is not a rotation"),
    (dict(angular_velocity=np.zeros((4, 3, 3))), r"angular_velocity has shape \[4, 3, 3\], expected \[4, 2, 3\]"),
    (dict(time=np.arange(4, dtype=np.float32)), "time must be a float64"),
    (dict(links=("Pelvis", "Pelvis")), "duplicate link names"),
    (dict(external_wrench=np.zeros((4, 2, 3))), r"external_wrench must be float64 \[4,2,6\], got float64 \[4, 2, 3\]"),
    (dict(external_wrench=np.full((4, 2, 6), np.inf)), "external_wrench holds Inf"),
])
def test_invalid_recordings_are_refused_naming_the_problem(change, message):
    with pytest.raises(RecordingError, match=message):
        Recording(**valid(**change))


def test_an_external_wrench_round_trips_with_its_unknown_frames(tmp_path):
    wrench = np.random.default_rng(1).normal(size=(4, 2, 6))
    wrench[2, 1] = np.nan  # measured but not given to one segment
    back = load_recording(save_recording(Recording(**valid(external_wrench=wrench)), tmp_path / "w.npz"))
    assert np.array_equal(back.external_wrench, wrench, equal_nan=True)
    assert load_recording(save_recording(Recording(**valid()), tmp_path / "none.npz")).external_wrench is None


def test_a_reflection_is_not_a_rotation():
    R = valid()["orientation"].copy()
    R[2, 1] = -R[2, 1]
    with pytest.raises(RecordingError, match="'Head' at frame 2 is not a rotation"):
        Recording(**valid(orientation=R))


def test_loading_names_the_file_and_what_is_missing(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        load_recording(tmp_path / "none.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(RecordingError, match="junk.npz: not a torchik recording"):
        load_recording(tmp_path / "junk.npz")
    np.savez(tmp_path / "partial.npz", time=np.zeros(3))
    with pytest.raises(RecordingError, match=r"partial.npz: missing \['links'"):
        load_recording(tmp_path / "partial.npz")


def test_finite_difference_angular_velocity_of_a_constant_spin():
    t = np.linspace(0, 1, 101)
    w = np.array([0.3, -0.2, 1.5])
    R = so3.exp(torch.from_numpy(t[:, None] * w)).numpy()[:, None]  # [T,1,3,3], world-frame spin
    estimate = angular_velocity_from_orientations(R, t)
    assert np.allclose(estimate, w, atol=1e-10)


def test_messages_name_what_the_input_is_and_print_times_as_plain_numbers(tmp_path):
    with pytest.raises(RecordingError, match="is a folder; give a recording file"):
        load_recording(tmp_path)
    (tmp_path / "notes.npz").write_text("time,x\n0,1\n")
    with pytest.raises(RecordingError, match=r"notes.npz: not a torchik recording \(.npz, a zip archive") as caught:
        load_recording(tmp_path / "notes.npz")
    assert "pickle" not in str(caught.value)
    with pytest.raises(RecordingError, match=r"frame 2 at 0.01 s follows 0.01 s$"):
        Recording(**valid(time=np.array([0.0, 0.01, 0.01, 0.03])))


@pytest.mark.parametrize("scale, accepted", [(1 + 1e-5, True), (1 + 2.5e-3, True), (1 + 2e-2, False)])
def test_rotations_within_the_trackers_projection_tolerance_load_and_are_projected_and_counted(tmp_path, scale, accepted):
    from torchik.io import recording_targets
    from torchik.method.targets import PROJECT_TOLERANCE, clean_targets

    R = valid()["orientation"].copy()
    R[1, 0] *= scale  # ||R^T R - I|| = sqrt(3) (scale^2 - 1): 3.5e-5, 8.7e-3, 6.9e-2
    deviation = np.linalg.norm(R[1, 0].T @ R[1, 0] - np.eye(3))
    assert (deviation <= PROJECT_TOLERANCE) == accepted
    if not accepted:
        with pytest.raises(RecordingError, match="'Pelvis' at frame 1 is not a rotation"):
            Recording(**valid(orientation=R))
        return
    path = save_recording(Recording(**valid(orientation=R)), tmp_path / "near.npz")
    rec = load_recording(path)
    assert np.array_equal(rec.orientation, R)  # kept as measured: the tracker projects it
    sequence = recording_targets(rec, ("Pelvis", "Head"))
    assert [int(clean_targets(sequence[k]).projected.sum()) for k in range(4)] == [0, 1, 0, 0]


def test_read_names_a_folder_as_a_folder_whatever_its_suffix(tmp_path):
    from torchik.io import read

    for name in ("session", "session.bvh"):
        (tmp_path / name).mkdir()
        with pytest.raises(RecordingError, match=f"{name}: is a folder; give a recording file"):
            read(tmp_path / name)
