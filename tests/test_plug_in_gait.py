"""pipelines/plug_in_gait.py: Plug-in Gait's own kinetics read from the shared Vicon walks, and
torchik's sagittal joint powers against them (experiments/dynamics.md)."""

import numpy as np
import pytest
import torch
from conftest import shared_file, skip_without_shared

from torchik.io import map_recording, read
from torchik.io.c3d import _labels, read_c3d
from torchik.io.subjects import subject_from_recording
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.pipelines.dynamics import motion_dynamics
from torchik.pipelines.plug_in_gait import SEGMENTS, agreement, plug_in_gait_kinetics

ezc3d = pytest.importorskip("ezc3d")

# each walk, its static trial, and the lowest r of its sides' hip, knee and ankle powers in stance as
# measured on 2026-11-28 (experiments/dynamics.md): sagittal against Plug-in Gait's sagittal term, total
# against its stored power
MEASURED = {"HC002D06": ("HC002D02", 0.936, 0.956), "HC002D25": ("HC002D02", 0.936, 0.970),
            "HC030A05": ("HC030A01", 0.935, 0.984), "HC030A22": ("HC030A01", 0.920, 0.985)}
MARGIN = 0.02


@skip_without_shared
@pytest.mark.parametrize("walk", list(MEASURED))
def test_plug_in_gaits_power_is_its_moment_dotted_with_the_joints_relative_angular_velocity(walk):
    """The stored `<S><J>Power` holds the total power in z alone (x and y are 0), and a sum over the nine
    products of the moment's and the relative angular velocity's components in the distal segment's
    frame reproduces it (r >= 0.999) with the sagittal product M_x w_y's coefficient held at +1 at the hip
    and ankle and -1 at the knee (a free fit puts it within 0.25 of that; the ankle's other products are
    nearly collinear): what plug_in_gait.py reads."""
    path = shared_file(f"c3d/{walk}.c3d")
    c3d = ezc3d.c3d(str(path))
    labels = _labels(c3d["parameters"]["POINT"])
    points = c3d["data"]["points"][:3]
    recording = read_c3d(path, forces=False)
    segment = {name: i for i, name in enumerate(recording.links)}
    for side in "LR":
        for joint, sign in (("Hip", 1.0), ("Knee", -1.0), ("Ankle", 1.0)):
            power = points[:, labels.index(f"{side}{joint}Power")].T
            moment = points[:, labels.index(f"{side}{joint}Moment")].T / 1000.0
            proximal, distal = (side + s if s != "PEL" else s for s in SEGMENTS[joint])
            R = recording.orientation[:, segment[distal]]
            w = recording.angular_velocity[:, segment[distal]] - recording.angular_velocity[:, segment[proximal]]
            local = np.einsum("tji,tj->ti", R, w)
            ok = np.isfinite(local).all(-1) & np.isfinite(moment).all(-1) & (np.abs(moment).sum(-1) > 0)
            assert np.abs(power[ok, :2]).max() == 0.0
            products = (moment[ok, :, None] * local[ok, None, :]).reshape(-1, 9)
            sagittal = sign * products[:, 1]  # M_x w_y, its coefficient held at the sign
            others = np.delete(products, 1, axis=1)
            fit = sagittal + others @ np.linalg.lstsq(others, power[ok, 2] - sagittal, rcond=None)[0]
            assert np.corrcoef(fit, power[ok, 2])[0, 1] > 0.999, (side, joint)
            free = np.linalg.lstsq(products, power[ok, 2], rcond=None)[0][1]
            assert abs(free - sign) < 0.25, (side, joint, free)  # and a free fit finds it near


@skip_without_shared
@pytest.mark.parametrize("walk", list(MEASURED))
def test_the_sagittal_powers_in_stance_follow_plug_in_gaits(walk):
    """`torchik dynamics`' pipeline with Human66 (the subject from the static trial): for every side whose
    foot stands on a plate, the hip, knee and ankle powers correlate with Plug-in Gait's over that stance
    at least as well as measured, less 0.02 (sagittal and total; 0.90 and more sagittal everywhere)."""
    static_name, sagittal, total = MEASURED[walk]
    static, path = read(shared_file(f"c3d/{static_name}.c3d")), shared_file(f"c3d/{walk}.c3d")
    model = load_model("human66", subject_from_recording(static, map_name="plugin_gait_to_human").subject)
    recording, _ = map_recording(read(path), "plugin_gait_to_human", model, static)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        dynamics = motion_dynamics(model, recording, [link for link in TRACKED_LINKS["human66"]
                                                      if link in recording.links])
    finally:
        torch.set_num_threads(threads)
    rows = agreement(dynamics, plug_in_gait_kinetics(path))
    assert {(a.side, a.joint) for a in rows} == {(s, j) for s in ("Right", "Left") for j in ("Hip", "Knee", "Ankle")}
    for a in rows:
        assert a.r_sagittal >= sagittal - MARGIN and a.r_sagittal >= 0.9, a
        assert a.r_total >= total - MARGIN, a


@skip_without_shared
def test_plug_in_gaits_values_per_kg_of_bodymass_become_per_kg_of_the_models_mass():
    """Plug-in Gait divides by PROCESSING:Bodymass (HC002's 32.1 kg); the comparison takes its values per kg
    of the model's mass (what the static trial's plates weigh, 31.07 kg): the same joint's W, one mass."""
    kinetics = plug_in_gait_kinetics(shared_file("c3d/HC002D06.c3d"))
    knee = kinetics[("Right", "Knee")]
    assert knee.bodymass == pytest.approx(32.1, abs=1e-4)
    weighed = knee.per_kg_of(31.07)
    assert weighed.bodymass == 31.07
    for ours, theirs in ((weighed.moment, knee.moment), (weighed.sagittal_power, knee.sagittal_power),
                         (weighed.total_power, knee.total_power)):
        np.testing.assert_allclose(ours * 31.07, theirs * knee.bodymass, equal_nan=True)
