"""io.force_plates, io.analog, io.foot_contacts: ground reactions from a C3D file's plates.

Files written here hold plates of known corners and ORIGIN whose channels carry the wrench of a
known force at a known centre of pressure with a known free moment: the reader must give them back
(one plate turned 30 degrees, ORIGIN in Vicon's sign and in the C3D manual's). The shared walks'
plates must give Plug-in Gait's own ground reactions (its `GroundReactionForce` and
`GroundReactionMoment` points), each on the foot Plug-in Gait gave it."""

import numpy as np
import pytest
from conftest import shared_file

from torchik.io import Recording, apply_map, load_recording, save_recording
from torchik.io.analog import to_frames
from torchik.io.c3d import _labels, read_c3d, read_ground_reactions
from torchik.io.maps import LinkEntry, LinkMap
from torchik.io.recording import RecordingError

ezc3d = pytest.importorskip("ezc3d")

RATE, ANALOG_RATE = 100.0, 1000.0
DOWN = np.diag([1.0, -1.0, -1.0])  # a plate's x along the lab's, its z down (as plates lie in floors)


def turn(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class Plate:
    """A plate in the lab (mm): R [3,3] plate frame to lab, surface centre c, half sizes, and the
    vector from the surface centre to the transducer origin in the plate frame, stored in ORIGIN
    with Vicon's sign (+z) or the C3D manual's (the opposite vector, -z)."""

    def __init__(self, R, centre, half=(232.0, 254.0), to_origin=(1.4, -0.3, 40.0), vicon_sign=True):
        self.R, self.centre, self.half = R, np.asarray(centre, float), half
        self.to_origin = np.asarray(to_origin)
        self.stored_origin = self.to_origin if vicon_sign else -self.to_origin

    def corners(self) -> np.ndarray:  # [3,4]: quadrants +x+y, -x+y, -x-y, +x-y of the plate frame
        a, b = self.half
        local = np.array([[a, b, 0], [-a, b, 0], [-a, -b, 0], [a, -b, 0]])
        return (self.centre + local @ self.R.T).T

    def channels(self, force, cop, free) -> np.ndarray:
        """[S,6] Fx..Mz (N, N mm) in the plate frame about the transducer origin, for the force the plate
        exerts on the body force [S,3] (N, lab) at cop [S,3] (mm) with the free moment free [S] (N mm)."""
        origin = self.centre + self.R @ self.to_origin
        moment = free[:, None] * np.array([0.0, 0.0, 1.0]) + np.cross(cop - origin, force)
        return np.concatenate((force @ self.R, moment @ self.R), axis=1)


def write_plates(path, plates, signals, frames, markers=None, segments=("PEL", "LFO", "RFO")):
    """A C3D file (mm) with `plates` whose channels hold `signals` [S,6] each, and static points:
    each segment's triad and the markers {label: [3] mm}."""
    labels, columns = [], []
    for k, segment in enumerate(segments):
        origin = np.array([0.0, 300.0 * k, 900.0])
        for axis, offset in zip("OALP", (np.zeros(3), *np.eye(3) * 90.0)):
            labels.append(segment + axis)
            columns.append(origin + offset)
    for label, xyz in (markers or {}).items():
        labels.append(label)
        columns.append(np.asarray(xyz, float))
    points = np.ones((4, len(labels), frames))
    points[:3] = np.stack(columns, 1)[:, :, None]
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [RATE]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    c3d.add_parameter("POINT", "UNITS", ["mm"])
    c3d["data"]["points"] = points
    add_plates(c3d, plates, signals)
    c3d.write(str(path))
    return path


def add_plates(c3d, plates, signals) -> None:
    """`plates` (type 2) in an ezc3d file object, their analog channels (N, N mm) holding `signals` [S,6] each."""
    names = [f"{q}{k + 1}" for k in range(len(plates)) for q in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")]
    c3d["parameters"]["ANALOG"]["RATE"]["value"] = [ANALOG_RATE]
    c3d["parameters"]["ANALOG"]["LABELS"]["value"] = tuple(names)
    c3d.add_parameter("ANALOG", "UNITS", ["N", "N", "N", "Nmm", "Nmm", "Nmm"] * len(plates))
    c3d["data"]["analogs"] = np.concatenate(signals, axis=1).T[None]
    c3d.add_parameter("FORCE_PLATFORM", "USED", [len(plates)])
    c3d.add_parameter("FORCE_PLATFORM", "TYPE", [2] * len(plates))
    c3d.add_parameter("FORCE_PLATFORM", "ZERO", [1, 0])
    c3d.add_parameter("FORCE_PLATFORM", "CORNERS", np.stack([p.corners() for p in plates], axis=2))
    c3d.add_parameter("FORCE_PLATFORM", "ORIGIN", np.stack([p.stored_origin for p in plates], axis=1))
    c3d.add_parameter("FORCE_PLATFORM", "CHANNEL", np.arange(1.0, 6 * len(plates) + 1).reshape(len(plates), 6).T)


def constant(value, samples) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, float), (samples, *np.shape(value))).copy()


@pytest.fixture
def two_plates(tmp_path):
    """Plate 1 as the shared files' lie (x along the lab's, z down, Vicon's ORIGIN); plate 2 turned
    30 degrees about the vertical, with the manual's ORIGIN. 40 frames, each plate under a constant
    wrench: the force, centre of pressure (mm) and free moment (N mm) it was written from."""
    frames, S = 40, 400
    plates = (Plate(DOWN, (232.0, 254.0, 0.0)),
              Plate(turn(np.pi / 6) @ DOWN, (300.0, -400.0, 0.0), half=(200.0, 300.0), to_origin=(-2.0, 3.0, 35.0),
                    vicon_sign=False))
    truth = [(np.array([12.0, -30.0, 420.0]), np.array([250.0, 300.0, 0.0]), 1500.0),
             (np.array([-25.0, 8.0, 380.0]), np.array([350.0, -350.0, 0.0]), -2200.0)]
    signals = [plate.channels(constant(f, S), constant(p, S), constant(t, S)) for plate, (f, p, t) in zip(plates, truth)]
    markers = {"LHEE": (240.0, 200.0, 25.0), "LTOE": (240.0, 380.0, 35.0),  # the left foot over plate 1's COP
               "RHEE": (340.0, -450.0, 25.0), "RTOE": (360.0, -280.0, 35.0)}  # the right over plate 2's
    return write_plates(tmp_path / "plates.c3d", plates, signals, frames, markers), truth


@pytest.mark.parametrize("method", ["butterworth", "mean"])
def test_a_known_wrench_gives_its_force_centre_of_pressure_and_free_moment(two_plates, method):
    path, truth = two_plates
    g = read_ground_reactions(path, method=method)
    assert [p.number for p in g.plates] == [1, 2] and g.force.shape == (40, 2, 3) and g.signs == (1, 1)
    for k, (force, cop, free) in enumerate(truth):
        # C3D stores float32: 1e-7 of 420 N and of the moments' 1e5 N mm
        np.testing.assert_allclose(g.force[:, k], np.broadcast_to(force, (40, 3)), atol=1e-4, rtol=0)
        np.testing.assert_allclose(g.cop[:, k], np.broadcast_to(cop * 1e-3, (40, 3)), atol=1e-6, rtol=0)
        np.testing.assert_allclose(g.free_moment[:, k], free * 1e-3, atol=1e-5, rtol=0)
        about_origin = np.cross(cop * 1e-3, force) + [0, 0, free * 1e-3]
        np.testing.assert_allclose(g.moment[:, k], np.broadcast_to(about_origin, (40, 3)), atol=1e-4, rtol=0)
    assert g.contact.all()
    np.testing.assert_allclose(g.plates[1].rotation, turn(np.pi / 6) @ DOWN, atol=1e-7)  # float32 corners
    np.testing.assert_allclose(g.plates[0].up, [0, 0, 1], atol=1e-12)


def test_below_the_threshold_a_plate_is_unloaded_and_its_centre_of_pressure_unknown(tmp_path):
    """A vertical force rising linearly from 0 to 60 N over the trial (a line: the zero-phase filter
    keeps it, but for 0.1 N over the last frames, where its padding ends): loaded from the first frame
    above 20 N, with force zero and COP NaN before."""
    frames = 60
    S = frames * 10
    plate = Plate(DOWN, (232.0, 254.0, 0.0))
    t = np.arange(S) / ANALOG_RATE
    force = np.stack((0 * t, 0 * t, 60.0 * t / t[-1]), 1)
    signals = [plate.channels(force, constant([200.0, 250.0, 0.0], S), 0 * t)]
    g = read_ground_reactions(write_plates(tmp_path / "ramp.c3d", [plate], signals, frames))
    fz = 60.0 * np.arange(frames) * 10 / (S - 1)
    assert np.array_equal(g.contact[:, 0], fz > 20.0) and g.threshold == 20.0
    np.testing.assert_allclose(g.force[:-10, 0, 2], np.where(fz > 20, fz, 0.0)[:-10], atol=1e-3)
    assert np.isnan(g.cop[~g.contact[:, 0], 0]).all() and (g.free_moment[~g.contact[:, 0]] == 0).all()
    np.testing.assert_allclose(g.cop[g.contact[:, 0], 0], np.broadcast_to([0.2, 0.25, 0], (g.contact.sum(), 3)), atol=1e-6)


def test_channels_holding_the_force_on_the_plate_are_turned_into_the_force_on_the_body(tmp_path):
    plate = Plate(DOWN, (232.0, 254.0, 0.0))
    S = 200
    signals = [-plate.channels(constant([5.0, 0, 400.0], S), constant([200.0, 250.0, 0.0], S), constant(300.0, S))]
    g = read_ground_reactions(write_plates(tmp_path / "action.c3d", [plate], signals, 20))
    assert g.signs == (-1,)
    np.testing.assert_allclose(g.force[:, 0], np.broadcast_to([5.0, 0, 400.0], (20, 3)), atol=1e-4)
    np.testing.assert_allclose(g.cop[:, 0], np.broadcast_to([0.2, 0.25, 0], (20, 3)), atol=1e-6)


def test_the_resampling_filter_has_no_lag_and_keeps_what_the_frames_cannot_hold_from_aliasing():
    t = np.arange(2000) / ANALOG_RATE
    slow, fast = np.sin(2 * np.pi * 3 * t), np.sin(2 * np.pi * 95 * t)  # 95 Hz decimated to 100 Hz: a 5 Hz alias
    frames = t[::10]
    got = to_frames(np.stack((slow, fast), 1), ANALOG_RATE, RATE, 200)
    inner = slice(20, -20)  # away from the ends' padding
    np.testing.assert_allclose(got[inner, 0], np.sin(2 * np.pi * 3 * frames)[inner], atol=1e-3)  # no lag, gain 1
    assert np.abs(fast[::10]).max() > 0.9 and np.abs(got[inner, 1]).max() < 1e-3
    mean = to_frames(np.stack((slow, fast), 1), ANALOG_RATE, RATE, 200, method="mean")
    k = 57
    np.testing.assert_allclose(mean[k], np.stack((slow, fast), 1)[10 * k - 5:10 * k + 6].mean(0), rtol=1e-12)
    with pytest.raises(ValueError, match="below|between 0 and"):
        to_frames(np.stack((slow, fast), 1), ANALOG_RATE, RATE, 200, cutoff=60.0)


def test_the_c3d_reader_puts_each_plates_wrench_on_the_foot_standing_on_it(two_plates, tmp_path):
    path, truth = two_plates
    rec = read_c3d(path)
    assert rec.external_wrench is not None and rec.external_wrench.shape == (40, 3, 6)
    contacts = rec.meta["force_plates"]["contacts"]
    assert [(c["plate"], c["link"], c["start_frame"], c["stop_frame"]) for c in contacts] == [(1, "LFO", 0, 40),
                                                                                              (2, "RFO", 0, 40)]
    for link, (force, cop, free) in zip(("LFO", "RFO"), truth):
        w = rec.external_wrench[:, rec.links.index(link)]
        np.testing.assert_allclose(w[:, :3], np.broadcast_to(force, (40, 3)), atol=1e-4)
        np.testing.assert_allclose(w[:, 3:], np.broadcast_to(np.cross(cop * 1e-3, force) + [0, 0, free * 1e-3], (40, 3)),
                                   atol=1e-4)
    assert (rec.external_wrench[:, rec.links.index("PEL")] == 0).all()
    assert rec.meta["force_plates"]["threshold_n"] == 20.0 and rec.meta["force_plates"]["resampling"]["cutoff_hz"] == 30.0
    assert read_c3d(path, forces=False).external_wrench is None
    back = load_recording(save_recording(rec, tmp_path / "r.npz"))
    assert np.array_equal(back.external_wrench, rec.external_wrench)


def test_two_feet_on_one_plate_share_it_and_their_wrenches_are_unknown(tmp_path):
    plate = Plate(DOWN, (232.0, 254.0, 0.0))
    S = 200
    signals = [plate.channels(constant([0, 0, 400.0], S), constant([232.0, 300.0, 0.0], S), constant(0.0, S))]
    markers = {"LHEE": (330.0, 200.0, 25.0), "LTOE": (330.0, 380.0, 35.0),
               "RHEE": (130.0, 200.0, 25.0), "RTOE": (130.0, 380.0, 35.0)}
    rec = read_c3d(write_plates(tmp_path / "static.c3d", [plate], signals, 20, markers))
    (contact,) = rec.meta["force_plates"]["contacts"]
    assert contact["link"] is None and contact["shared"] == ["LFO", "RFO"]
    assert np.isnan(rec.external_wrench[:, 1:]).all() and (rec.external_wrench[:, 0] == 0).all()


def test_a_foot_whose_heel_lies_beyond_the_plates_edge_overhangs_it(tmp_path):
    """The contact stays the foot's, its frames marked: the heel may rest on the floor beside the plate
    (HC002D25's right heel, 20 mm over plate 2's edge, as here)."""
    plates = (Plate(DOWN, (232.0, 254.0, 0.0)), Plate(DOWN, (232.0, -324.0, 0.0)))  # y 0..508 and -578..-70
    S = 200
    signals = [plate.channels(constant([0, 0, 300.0], S), constant(cop, S), constant(0.0, S))
               for plate, cop in zip(plates, ([232.0, 100.0, 0.0], [232.0, -300.0, 0.0]))]
    markers = {"LHEE": (232.0, -20.0, 25.0), "LTOE": (232.0, 150.0, 35.0),  # heel 20 mm beyond plate 1's edge
               "RHEE": (232.0, -400.0, 25.0), "RTOE": (232.0, -240.0, 35.0)}  # wholly over plate 2
    rec = read_c3d(write_plates(tmp_path / "edge.c3d", plates, signals, 20, markers))
    left, right = rec.meta["force_plates"]["contacts"]
    assert left["link"] == "LFO" and left["overhang_frames"] == [[0, 20]]
    assert right["link"] == "RFO" and right["overhang_frames"] == []
    np.testing.assert_allclose(rec.external_wrench[:, rec.links.index("LFO"), 2], 300.0, atol=1e-3)  # still the foot's


def test_a_plate_far_from_every_foot_is_given_to_none(tmp_path):
    plate = Plate(DOWN, (232.0, 254.0, 0.0))
    S = 200
    signals = [plate.channels(constant([0, 0, 100.0], S), constant([232.0, 254.0, 0.0], S), constant(0.0, S))]
    markers = {"LHEE": (1000.0, 200.0, 25.0), "LTOE": (1000.0, 380.0, 35.0)}
    rec = read_c3d(write_plates(tmp_path / "hand.c3d", [plate], signals, 20, markers))
    (contact,) = rec.meta["force_plates"]["contacts"]
    assert contact["link"] is None and contact["distance_m"] > 0.7 and (rec.external_wrench == 0).all()


def test_a_map_carries_each_segments_wrench_to_one_link():
    T = 5
    wrench = np.arange(T * 3 * 6, dtype=float).reshape(T, 3, 6)
    rec = Recording(time=np.arange(T) / RATE, links=("PEL", "LFO", "RFO"), orientation=np.tile(np.eye(3), (T, 3, 1, 1)),
                    angular_velocity=np.zeros((T, 3, 3)), base_link="PEL", base_position=np.zeros((T, 3)),
                    base_linear_velocity=np.zeros((T, 3)), external_wrench=wrench)
    entries = tuple(LinkEntry(link, segment, np.eye(3)) for link, segment in
                    (("Pelvis", "PEL"), ("RightFoot", "RFO"), ("LeftFoot", "LFO"), ("LeftToe", "LFO")))
    mapped = apply_map(rec, LinkMap("test", "human", entries, "Pelvis", "PEL", None, None, "<test>"))
    assert np.array_equal(mapped.external_wrench[:, :3], wrench[:, [0, 2, 1]])
    assert (mapped.external_wrench[:, 3] == 0).all()  # the left foot's wrench once, on LeftFoot
    assert np.array_equal(mapped.part(1, 3).external_wrench, mapped.external_wrench[1:3])


def test_a_plate_of_another_type_is_skipped_and_named(two_plates):
    path, _ = two_plates
    c3d = ezc3d.c3d(str(path))
    c3d["parameters"]["FORCE_PLATFORM"]["TYPE"]["value"] = np.array([2, 4])
    c3d.write(str(path))
    g = read_ground_reactions(path)
    assert [p.number for p in g.plates] == [1]
    assert g.skipped == ["plate 2: type 4 is not read (only type 2, forces and moments)"]
    c3d["parameters"]["FORCE_PLATFORM"]["TYPE"]["value"] = np.array([2, 2])
    c3d["parameters"]["FORCE_PLATFORM"]["CHANNEL"]["value"] = np.array([[1, 7], [2, 8], [3, 9], [4, 10], [5, 11], [6, 40]])
    c3d.write(str(path))
    with pytest.raises(RecordingError, match="plates.c3d: FORCE_PLATFORM:CHANNEL names channel 40; the file has 12"):
        read_c3d(path)
    assert read_c3d(path, forces=False).external_wrench is None


WALKS = ["HC002D06.c3d", "HC002D25.c3d", "HC030A05.c3d", "HC030A22.c3d"]
STATIC = ["HC002D02.c3d", "HC030A01.c3d"]


def plug_in_gait_reactions(path, side: str):
    """Plug-in Gait's ground reaction on foot `side` (L, R): force [T,3] N and moment about the plate's
    surface centre [T,3] N m, lab frame, on the body; the points hold them per kg of PROCESSING:Bodymass
    (N/kg and N mm/kg, whatever POINT:FORCE_UNITS says), NaN off the plates. And the body weight, N."""
    c3d = ezc3d.c3d(str(path))
    labels = _labels(c3d["parameters"]["POINT"])
    mass = float(c3d["parameters"]["PROCESSING"]["Bodymass"]["value"][0])
    point = lambda name: c3d["data"]["points"][:3, labels.index(side + name)].T * mass  # noqa: E731
    return point("GroundReactionForce"), point("GroundReactionMoment") * 1e-3, mass * 9.81


@pytest.mark.parametrize("name", WALKS + STATIC)
def test_the_shared_plates_give_plug_in_gaits_own_ground_reactions(name):
    """With Vicon's resampling (the centred 11-sample mean) the plates give Plug-in Gait's force and
    moment about the plate's centre to float32's rounding (measured: 3e-5 N, 4e-5 N m), in stance,
    on the foot Plug-in Gait gave the plate (a static trial's feet share plate 1, which it gives to the
    left foot). The default Butterworth at 30 Hz differs from that mean by what lies between 30 and 90 Hz:
    measured up to 1.6 % of body weight rms and 13 % at a heel strike."""
    path = shared_file(f"c3d/{name}")
    contacts = read_c3d(path).meta["force_plates"]["contacts"]
    assert [c["plate"] for c in contacts] == ([1, 2] if name in WALKS else [1])
    for method, force_tolerance, moment_tolerance in (("mean", 1e-3, 1e-3), ("butterworth", None, None)):
        g = read_ground_reactions(path, method=method)
        about_centre = g.moment_about(np.stack([p.centre for p in g.plates]))
        for contact in contacts:
            k = contact["plate"] - 1
            if name in WALKS:
                side = contact["link"][0]
                assert contact["distance_m"] < 0.01  # the centre of pressure under the heel-toe line
            else:
                side = "L"
                assert contact["link"] is None and contact["shared"] == ["LFO", "RFO"]
            force, moment, weight = plug_in_gait_reactions(path, side)
            stance = g.contact[:, k] & np.isfinite(force).all(1)
            stance[[0, -1]] = False  # the file's ends: Vicon's mean reached samples before and after the cut
            assert stance.sum() > 40
            df, dm = g.force[stance, k] - force[stance], about_centre[stance, k] - moment[stance]
            if force_tolerance is not None:
                assert np.abs(df).max() < force_tolerance and np.abs(dm).max() < moment_tolerance
            else:
                assert np.sqrt((df ** 2).mean()) < 0.02 * weight and np.abs(df).max() < 0.15 * weight
