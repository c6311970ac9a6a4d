"""rrd: a tracked sequence written to .rrd reads back, through rerun's dataframe API, with the
entity tree, the number of time steps and the values the tracker computed."""

import numpy as np
import pytest
import rerun.chunk
import torch

from torchik import InputError, so3
from torchik.io.targets import recording_targets
from torchik.method.models import TRACKED_LINKS, human_urdf, icub_urdf_path, load_model
from torchik.method.tracker import DynamicalIK
from torchik.pipelines.evaluation import tracking_errors
from torchik.pipelines.rrd import log_trajectory, quaternion_xyzw, visuals
from torchik.pipelines.track import track_recording
from torchik.synthetic.motion import periodic_motion, targets_from_motion
from torchik.synthetic.scenarios import scenario


def read_rrd(path, contents, index="time"):
    """Rows of `contents` (entity path expressions) on `index`, as pandas, by rerun's dataframe API."""
    store = rerun.chunk.RrdReader(path).store().stream().collect()
    return store.reader(index=index, contents=contents).to_pandas()


def entity_paths(path) -> set[str]:
    return set(rerun.chunk.RrdReader(path).store().schema().entity_paths())


def seconds(frame) -> np.ndarray:
    return frame["time"].to_numpy().astype("timedelta64[ns]").astype(np.int64) / 1e9


def column(frame, entity: str, component: str = "Scalars:scalars") -> np.ndarray:
    """A column as [rows, k, ...] float64 (k instances per row, each a scalar or a vector)."""
    return np.stack([np.array(v.tolist(), dtype=np.float64) for v in frame[f"{entity}:{component}"]])


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """Human66 tracking 0.5 s of the walking scenario, written to .rrd with its targets."""
    model, links = load_model("human66"), TRACKED_LINKS["human66"]
    recording = scenario("walking", model, links, duration=0.5)
    trajectory, _ = track_recording(model, recording, links)
    targets = recording_targets(recording, links)
    path = log_trajectory(tmp_path_factory.mktemp("rrd") / "walk.rrd", model, links, trajectory, targets,
                          urdf=human_urdf(66))
    return model, links, trajectory, targets, path


def test_one_subject_has_its_entity_tree_and_a_blueprint(walk):
    model, links, _, _, path = walk
    paths = entity_paths(path)
    for link in links:
        assert {f"/subject/0/estimate/{link}", f"/subject/0/estimate/{link}/visual", f"/subject/0/target/{link}",
                f"/subject/0/residual/orientation/{link}"} <= paths
    assert {f"/subject/0/joints/{joint}" for joint in model.joint_names} <= paths
    assert {"/subject/0/errors/mnte", "/subject/0/errors/rmse", "/subject/0/solver/active_constraints",
            "/subject/0/solver/solved", "/subject/0/skeleton", "/subject/0/residual/position/Pelvis",
            "/timing/step_time"} <= paths
    assert not any(p.startswith("/aggregate") for p in paths)  # one subject: nothing to aggregate
    assert [entry.kind for entry in rerun.chunk.RrdReader(path).blueprints()] == ["blueprint"]


def test_scalar_series_equal_the_trackers_results_at_every_step(walk):
    model, links, trajectory, _, path = walk
    joint = model.joint_names.index("jRightKnee_roty")
    frame = read_rrd(path, ["/subject/0/errors/**", "/subject/0/joints/jRightKnee_roty", "/timing/step_time",
                            "/subject/0/residual/orientation/Head", "/subject/0/solver/active_constraints"])
    T = len(trajectory.time)
    assert len(frame) == T
    assert np.allclose(seconds(frame), trajectory.time.numpy(), atol=1e-9)
    d = trajectory.diagnostics
    assert np.array_equal(column(frame, "/subject/0/errors/mnte")[:, 0], d["mnte"][:, 0].numpy())
    assert np.array_equal(column(frame, "/subject/0/errors/rmse")[:, 0], d["rmse"][:, 0].numpy())
    assert np.array_equal(column(frame, "/subject/0/joints/jRightKnee_roty")[:, 0],
                          trajectory.joint_positions[:, 0, joint].numpy())
    head = 1 + links.index("Head")  # residual_norm: the base position target, then the orientations
    assert np.array_equal(column(frame, "/subject/0/residual/orientation/Head")[:, 0],
                          d["residual_norm"][:, 0, head].numpy())
    assert np.array_equal(column(frame, "/subject/0/solver/active_constraints")[:, 0],
                          d["active_constraints"][:, 0].double().numpy())
    assert np.allclose(column(frame, "/timing/step_time")[:, 0], d["step_time"].numpy() * 1e3, rtol=1e-12)


def test_link_frames_are_the_estimated_and_the_measured_poses(walk):
    model, links, trajectory, targets, path = walk
    k = links.index("LeftHand")
    frame = read_rrd(path, ["/subject/0/estimate/LeftHand", "/subject/0/target/LeftHand"])
    kin = model(trajectory.base_position[:, 0], trajectory.base_rotation[:, 0], trajectory.joint_positions[:, 0],
                ["LeftHand"], jacobian=False)
    translation = column(frame, "/subject/0/estimate/LeftHand", "Transform3D:translation").reshape(-1, 3)
    quaternion = column(frame, "/subject/0/estimate/LeftHand", "Transform3D:quaternion").reshape(-1, 4)
    assert np.allclose(translation, kin.position[:, 0].numpy(), atol=1e-5)  # the viewer's float32
    rotation = so3.quaternion_to_matrix(torch.from_numpy(quaternion[:, [3, 0, 1, 2]]))
    assert torch.allclose(rotation, kin.rotation[:, 0], atol=1e-5)
    measured = column(frame, "/subject/0/target/LeftHand", "Transform3D:quaternion").reshape(-1, 4)
    measured = so3.quaternion_to_matrix(torch.from_numpy(measured[:, [3, 0, 1, 2]]))
    assert torch.allclose(measured, targets.rotation[:, 0, k], atol=1e-5)


def test_the_body_is_drawn_with_the_urdfs_visual_shapes(walk):
    _, _, _, _, path = walk
    frame = read_rrd(path, "/subject/0/estimate/Pelvis/visual", index=None)
    logged = column(frame, "/subject/0/estimate/Pelvis/visual", "Boxes3D:half_sizes").reshape(-1, 3)
    (box,) = visuals(human_urdf(66))["Pelvis"]
    assert box.kind == "box" and np.allclose(logged, np.array(box.size) / 2)


def test_the_urdfs_visuals_cover_the_human_segments_and_find_icubs_meshes():
    human = visuals(human_urdf(66))
    assert set(human) == set(TRACKED_LINKS["human66"])
    assert {v.kind for vs in human.values() for v in vs} == {"box", "cylinder", "sphere"}
    icub = visuals(icub_urdf_path())
    meshes = [v for vs in icub.values() for v in vs if v.kind == "mesh"]
    assert meshes and all(v.mesh.is_file() for v in meshes)


def test_a_batch_has_one_tree_per_subject_and_their_mean_and_max(tmp_path):
    model, links = load_model("human48"), TRACKED_LINKS["human48"]
    motion = periodic_motion(model, 0.3, 100, batch=3)
    sequence = targets_from_motion(model, motion, links)
    trajectory = DynamicalIK(model, links, dt=0.01).run(sequence, motion.state(0), interruptible=True)
    trajectory.diagnostics.update(tracking_errors(model, trajectory, sequence, links))
    path = log_trajectory(tmp_path / "batch.rrd", model, links, trajectory, sequence)
    paths = entity_paths(path)
    assert {f"/subject/{i}/errors/mnte" for i in range(3)} <= paths and "/subject/3/errors/mnte" not in paths
    frame = read_rrd(path, [f"/subject/{i}/errors/rmse" for i in range(3)]
                     + ["/aggregate/errors/rmse", "/subject/1/joints/jRightKnee_roty"])
    assert len(frame) == len(trajectory.time) == 31
    each = np.stack([column(frame, f"/subject/{i}/errors/rmse")[:, 0] for i in range(3)], axis=1)
    assert np.array_equal(each, trajectory.diagnostics["rmse"].numpy())
    aggregate = column(frame, "/aggregate/errors/rmse")
    assert np.allclose(aggregate, np.stack((each.mean(1), each.max(1)), axis=1), rtol=1e-12)
    knee = model.joint_names.index("jRightKnee_roty")  # a joint with limits: angle, lower, upper
    logged = column(frame, "/subject/1/joints/jRightKnee_roty")
    assert np.array_equal(logged[:, 0], trajectory.joint_positions[:, 1, knee].numpy())
    assert np.all(logged[:, 1] == float(model.lower[knee])) and np.all(logged[:, 2] == float(model.upper[knee]))


def test_quaternions_give_back_the_rotation_even_near_half_turns():
    g = torch.Generator().manual_seed(0)
    R = so3.random_rotation((200,), g)
    axis = torch.nn.functional.normalize(torch.randn(50, 3, generator=g, dtype=torch.float64), dim=-1)
    half_turns = so3.exp((torch.pi - 1e-9) * axis)  # where the trace-based formula loses all precision
    R = torch.cat((R, half_turns, torch.eye(3, dtype=torch.float64)[None]))
    q = quaternion_xyzw(R)
    assert torch.allclose(q.norm(dim=-1), torch.ones(len(R), dtype=torch.float64))
    assert torch.allclose(so3.quaternion_to_matrix(q[:, [3, 0, 1, 2]]), R, atol=1e-12)


def test_a_write_that_fails_leaves_the_old_file_whole(walk, tmp_path, monkeypatch):
    model, links, trajectory, targets, _ = walk
    path = tmp_path / "walk.rrd"
    path.write_bytes(b"old")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("torchik.pipelines.rrd._send_scalars", interrupted)
    with pytest.raises(KeyboardInterrupt):
        log_trajectory(path, model, links, trajectory, targets)
    assert path.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["walk.rrd"]


def test_inputs_that_do_not_fit_the_trajectory_are_refused(walk, tmp_path):
    model, links, trajectory, targets, _ = walk
    with pytest.raises(InputError, match="subjects"):
        log_trajectory(tmp_path / "x.rrd", model, links, trajectory, subjects=[1])
    with pytest.raises(InputError, match="targets.rotation"):
        log_trajectory(tmp_path / "x.rrd", model, links[:-1], trajectory, targets)
    with pytest.raises(InputError, match="is it the model's URDF"):
        log_trajectory(tmp_path / "x.rrd", load_model("icub"), TRACKED_LINKS["icub"], trajectory, urdf=human_urdf(66))
    assert not (tmp_path / "x.rrd").exists()
