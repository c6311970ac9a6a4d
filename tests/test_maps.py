"""io.maps: link maps rename and re-frame a recording's segments; calibration recovers unknown offsets exactly."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from conftest import shared_file

from torchik.io import RecordingError, apply_map, calibrate, load_map
from torchik.io.maps import LinkEntry, LinkMap, built_in_maps, reference_configuration, resolve
from torchik.io.recording import Recording
from torchik.io.targets import recording_targets
from torchik.method import so3
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.state import State
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.scenarios import scenario


def test_the_human_to_icub_offsets_make_icubs_zero_configuration_the_human_t_pose_for_trunk_and_legs():
    """At the human T-pose every human link frame is the world's; iCub at zero (arms aside) must then match."""
    icub, link_map = load_model("icub"), load_map("human_to_icub")
    offset = {e.link: torch.from_numpy(e.offset) for e in link_map.entries}
    p, _, s = icub.zero_configuration(1)
    kin = icub(p, offset["root_link"][None], s, link_map.links, jacobian=False)
    for i, link in enumerate(link_map.links):
        angle = float(so3.log(kin.rotation[0, i].T @ offset[link]).norm())
        if "arm" in link or "hand" in link:
            assert abs(angle - np.pi / 2) < 0.02, link  # iCub's arms at zero are a quarter turn from a T
        else:
            assert angle < 1e-5, link  # the published foot offsets write pi as 3.14159


def test_a_retargeted_human_walk_is_tracked_by_icub_within_its_limits():
    human, icub = load_model("human66"), load_model("icub")
    mapped = apply_map(scenario("walking", human, TRACKED_LINKS["human66"], duration=5.0), load_map("human_to_icub"))
    targets = recording_targets(mapped, mapped.links)
    s0 = icub.zero_configuration(1)[2]
    for name, value in (("r_shoulder_roll", 0.6), ("l_shoulder_roll", 0.6), ("r_elbow", 0.3), ("l_elbow", 0.3)):
        s0[0, icub.joint_names.index(name)] = value  # a feasible start, near the human's posture
    start = State(targets.position[0, :, 0].clone(), targets.rotation[0, :, 0].clone(), s0,
                  torch.zeros(1, 6 + icub.n_dof, dtype=torch.float64))
    trajectory = DynamicalIK(icub, mapped.links, position_gain=10.0, orientation_gain=10.0, dt=0.01).run(targets, start)
    s = trajectory.joint_positions[:, 0]
    assert float(torch.maximum(s - icub.upper, icub.lower - s).max()) <= 1e-6
    assert float((s @ icub.linear_limits.A.T - icub.linear_limits.b).max()) <= 1e-6
    # iCub cannot match a human exactly (other segment proportions and joint axes): bounded, not zero
    assert float(trajectory.diagnostics["mnte"][200:].max()) < 0.02


def test_calibration_recovers_unknown_sensor_offsets_exactly():
    model = load_model("human48")
    links = TRACKED_LINKS["human48"]
    walk = scenario("walking", model, links, duration=1.0)
    # frame 0: the subject in an N-pose, facing 0.7 rad left of x; then walking
    p0, _, _ = model.zero_configuration(1)
    yaw = so3.exp(torch.tensor([[0.0, 0.0, 0.7]], dtype=torch.float64))
    reference = model(p0, yaw, reference_configuration(model, "npose"), links, jacobian=False).rotation[0].numpy()
    truth = np.concatenate((reference[None], walk.orientation))
    offsets = so3.random_rotation((len(links),), torch.Generator().manual_seed(0)).numpy()
    offsets[0] = np.eye(3)  # the pelvis sensor's x axis points forward, which calibration uses for the heading
    sensors = truth @ np.swapaxes(offsets, -1, -2)  # what misaligned sensors report: R_link D^T
    time = np.concatenate(([walk.time[0] - 0.01], walk.time))
    recording = Recording(time=time, links=tuple(f"s_{l}" for l in links), orientation=sensors,
                          angular_velocity=np.concatenate((np.zeros((1, len(links), 3)), walk.angular_velocity)),
                          base_link="s_Pelvis", base_position=np.concatenate((walk.base_position[:1], walk.base_position)),
                          base_linear_velocity=np.concatenate((walk.base_linear_velocity[:1], walk.base_linear_velocity)))
    link_map = LinkMap("test", "human48", tuple(LinkEntry(l, f"s_{l}", None) for l in links), "Pelvis", "s_Pelvis",
                       "npose", "x", "<test>")
    calibrated = calibrate(link_map, recording, model, frame=0)
    assert calibrated.calibration["frame"] == 0
    mapped = apply_map(recording, calibrated)
    assert np.abs(mapped.orientation - truth).max() < 1e-10
    assert mapped.meta["link_map"]["calibration"]["reference_pose"] == "npose"


def test_a_twist_calibration_keeps_the_segments_long_axis_and_finds_its_turn_about_it():
    """calibrate = "twist": a subject standing with a thigh bent 0.3 rad forward and 0.2 rad out, whose
    segment frame is also turned 0.4 rad about its long (z) axis from the link's: the offset is the turn
    about z alone (0.4 rad), so the mapped link's z axis is the segment's in every frame, where a full
    calibration would tilt it by the stance's 0.36 rad."""
    model = load_model("human48")
    p0, R0, _ = model.zero_configuration(1)
    reference = model(p0, R0, reference_configuration(model, "npose"), ["Pelvis", "RightUpperLeg"],
                      jacobian=False).rotation[0].numpy()
    stance = so3.exp(torch.tensor([0.2, -0.3, 0.0], dtype=torch.float64)).numpy()  # out and forward
    turn = so3.exp(torch.tensor([0.0, 0.0, 0.4], dtype=torch.float64)).numpy()
    later = so3.random_rotation((5,), torch.Generator().manual_seed(3)).numpy()
    thigh = np.concatenate(((stance @ reference[1] @ turn.T)[None], later))  # the segment: R_link C^T
    orientation = np.stack((np.broadcast_to(reference[0], thigh.shape), thigh), 1)
    T = len(thigh)
    recording = Recording(time=np.arange(T) / 100.0, links=("PEL", "RFE"), orientation=orientation,
                          angular_velocity=np.zeros((T, 2, 3)), base_link="PEL", base_position=np.zeros((T, 3)),
                          base_linear_velocity=np.zeros((T, 3)))
    entries = (LinkEntry("Pelvis", "PEL", None), LinkEntry("RightUpperLeg", "RFE", None, ("RFE",), twist_only=True))
    link_map = LinkMap("test", "human48", entries, "Pelvis", "PEL", "npose", "x", "<test>")
    calibrated = calibrate(link_map, recording, model, frame=0)
    np.testing.assert_allclose(calibrated.entries[1].offset, turn, atol=1e-12)
    mapped = apply_map(recording, calibrated)
    np.testing.assert_allclose(mapped.orientation[:, 1, :, 2], thigh[:, :, 2], atol=1e-12)
    full = calibrate(replace(link_map, entries=(entries[0], replace(entries[1], twist_only=False))), recording, model,
                     frame=0)
    tilt = np.arccos(apply_map(recording, full).orientation[0, 1, :, 2] @ thigh[0, :, 2])
    assert tilt == pytest.approx(np.arccos(stance[2, 2]), abs=1e-9) and tilt > 0.35


def test_maps_refuse_what_they_cannot_do():
    human = load_model("human66")
    rec = scenario("tpose", human, ["Pelvis", "Head"], duration=0.2)
    with pytest.raises(RecordingError, match="built-in maps: .*human_to_icub.*xsens_to_human"):
        load_map("bvh_to_robot")
    with pytest.raises(RecordingError, match="needs segment 'PEL', its base link 'Pelvis', that the recording lacks"):
        apply_map(rec, load_map("plugin_gait_to_human"))
    full = scenario("tpose", human, TRACKED_LINKS["human66"], duration=0.2)
    head_based = Recording(time=full.time, links=full.links, orientation=full.orientation,
                           angular_velocity=full.angular_velocity, base_link="Head", base_position=full.base_position,
                           base_linear_velocity=full.base_linear_velocity)
    with pytest.raises(RecordingError,
                       match="takes the base position from segment 'Pelvis'; the recording's base is 'Head'"):
        apply_map(head_based, load_map("xsens_to_human"))


@pytest.mark.parametrize("session", ["written", "shared"])
def test_plug_in_gait_calibrated_on_the_static_trial_then_applied_to_a_walk_is_tracked(session, request):
    """The session the tests write (conftest's pig_session), tracked with the model of the subject it
    was written from: the targets exactly; a real one (HC002) on a generic model: close, not exact."""
    from torchik.io import read_c3d

    if session == "written":
        written = request.getfixturevalue("pig_session")
        model, static, dynamic, bound = written.model, written.static, written.walk, 1e-6
    else:
        model, bound = load_model("human48"), 0.1
        static, dynamic = shared_file("c3d/HC002D02.c3d"), shared_file("c3d/HC002D25.c3d")
    calibrated = calibrate(load_map("plugin_gait_to_human"), read_c3d(static), model, frame=0)
    walk = apply_map(read_c3d(dynamic), calibrated)
    assert walk.links[0] == "Pelvis" and len(walk.links) == 19
    trajectory = DynamicalIK(model, walk.links, dt=0.01).run(recording_targets(walk, walk.links))
    assert bool(torch.isfinite(trajectory.joint_positions).all())
    assert float(trajectory.diagnostics["mnte"][100:].median()) < bound


def test_the_cmu_skeleton_calibrated_on_its_rest_pose_is_tracked_by_human66():
    from torchik.io import read_bvh

    model = load_model("human66")
    mapped = apply_map(read_bvh(shared_file("bvh/cmu_131_01.bvh")), load_map("cmu_to_human"), model)
    assert mapped.meta["link_map"]["calibration"]["frame"] == "rest"
    trajectory = DynamicalIK(model, mapped.links, dt=1 / 120).run(recording_targets(mapped, mapped.links))
    assert float(trajectory.diagnostics["mnte"][240:].median()) < 1e-4


def test_a_rest_pose_that_is_not_a_standing_posture_is_not_offered_for_calibration():
    from torchik.io import read_bvh

    bandai = read_bvh(shared_file("bvh/bandai_walk_normal_001.bvh"))  # every bone along x at rest
    assert bandai.meta["rest_pose"] is None
    link_map = LinkMap("bandai", "human66", (LinkEntry("Pelvis", "Hips", None), LinkEntry("Head", "Head", None)),
                       "Pelvis", "Hips", "npose", None, "<test>", None, "rest")
    with pytest.raises(RecordingError, match="rest pose is a standing posture"):
        calibrate(link_map, bandai, load_model("human66"))


def test_the_bandai_skeleton_calibrated_on_a_standing_frame_is_tracked_at_its_30_hz():
    from torchik.io import read_bvh

    model = load_model("human66")
    calibrated = calibrate(load_map("bandai_to_human"), read_bvh(shared_file("bvh/bandai_walk_normal_001.bvh")), model, 0)
    walk = apply_map(read_bvh(shared_file("bvh/bandai_walk_normal_002.bvh")), calibrated)
    trajectory = DynamicalIK(model, walk.links, position_gain=10.0, orientation_gain=10.0, dt=1 / 30).run(
        recording_targets(walk, walk.links))
    assert bool(torch.isfinite(trajectory.joint_positions).all()) and bool(trajectory.diagnostics["solved"].all())
    assert float(trajectory.diagnostics["mnte"][30:].median()) < 1e-3


def test_auto_names_the_closest_map_and_what_it_misses():
    from torchik.io.maps import choose_map

    assert choose_map(("Hips", "Spine", "Head", "LeftArm")) == "humanik_to_human"  # the rest left to the model
    with pytest.raises(RecordingError, match="the closest, 'humanik_to_human', misses its base segment 'Hips' and 16 more"):
        choose_map(("Spine", "Head", "LeftArm"))


LOWER_BODY = {"Pelvis": "PEL", "LeftUpperLeg": "LFE", "LeftLowerLeg": "LTI", "LeftFoot": "LFO", "LeftToe": "LTO",
              "RightUpperLeg": "RFE", "RightLowerLeg": "RTI", "RightFoot": "RFO", "RightToe": "RTO"}


def lower_body_plug_in_gait(duration: float = 1.0) -> Recording:
    """A Human48 walk with only the Plug-in Gait lower-body segments (the clinical marker set), in
    their names: PEL, LFE, LTI, LFO, LTO, RFE, RTI, RFO, RTO."""
    walk = scenario("walking", load_model("human48"), tuple(LOWER_BODY), duration=duration)
    return replace(walk, links=tuple(LOWER_BODY.values()), base_link="PEL")


def test_a_lower_body_plug_in_gait_recording_is_mapped_and_the_rest_is_left_to_the_model():
    from torchik.io import map_recording
    from torchik.io.maps import choose_map

    recording = lower_body_plug_in_gait()
    assert choose_map(recording.links) == "plugin_gait_to_human"
    mapped, _ = map_recording(recording, "auto", load_model("human48"))
    assert set(mapped.links) == set(LOWER_BODY) and mapped.links[0] == "Pelvis"
    assert mapped.meta["link_map"]["left_out"] == ["T8", "Head", "RightShoulder", "RightUpperArm", "RightForeArm",
                                                   "RightHand", "LeftShoulder", "LeftUpperArm", "LeftForeArm", "LeftHand"]
    assert mapped.meta["link_map"]["segments"] == LOWER_BODY


@pytest.mark.parametrize("name", built_in_maps())
def test_every_built_in_map_leaves_what_a_recording_lacks_to_the_model_and_needs_only_its_base(name):
    link_map = load_map(name)
    last = link_map.entries[-1]  # a toe or a foot: no other link's alternative
    resolved = resolve(link_map, (link_map.base_segment, last.segment, "Unrelated"))
    assert resolved.links == (link_map.base_link, last.link)
    assert resolved.left_out == tuple(e.link for e in link_map.entries[1:-1])
    with pytest.raises(RecordingError, match=f"needs segment '{link_map.base_segment}', its base link "
                                             f"'{link_map.base_link}', that the recording lacks: nothing to track"):
        resolve(link_map, tuple(e.segment for e in link_map.entries[1:]))


@pytest.mark.parametrize("file,explicit", [("written MVNX", "xsens_to_human"),
                                           ("written Plug-in Gait C3D", "plugin_gait_to_human"),
                                           ("bvh/cmu_131_01.bvh", "cmu_to_human"),
                                           ("bvh/bandai_walk_normal_001.bvh", "bandai_to_human"),
                                           ("mvnx/test_mocap.mvnx", "xsens_to_human")])
def test_auto_picks_each_files_map_with_the_same_result(file, explicit, request):
    """The files the tests write (an MVN export, a Plug-in Gait walk; the HumanIK BVH: test_skeletons)
    and the shared CMU, Bandai and MVNX files: --map auto is their explicit map, and the mapped
    recordings are the same arrays (so the tracking is the same)."""
    from torchik.io import map_recording, read

    path = {"written MVNX": lambda: request.getfixturevalue("mvn_export").path,
            "written Plug-in Gait C3D": lambda: request.getfixturevalue("pig_session").walk}.get(
        file, lambda: shared_file(file))()
    model = load_model("human48")
    recording = read(path)
    auto, auto_map = map_recording(recording, "auto", model)
    given, _ = map_recording(recording, explicit, model)
    assert auto_map.source == load_map(explicit).source
    assert auto.links == given.links
    np.testing.assert_array_equal(auto.orientation, given.orientation)
    np.testing.assert_array_equal(auto.base_position, given.base_position)
