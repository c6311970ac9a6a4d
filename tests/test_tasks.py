"""tasks and constraints: the step's tasks and limits beyond the paper's (tasks.py, constraints.py).

Properties:
- declaring the paper's tasks (OrientationTask, PositionTask) is the same tracker, to the bit;
- any other task makes the step dense, and a task of weight zero leaves the tree's solution (a batch
  of 128 on the batched backend) unchanged to 1e-10;
- the centre of mass and its MIXED Jacobian equal pinocchio's (Human66, Human48, iCub); a relative
  task's rows are the difference of iDynTree's MIXED frame Jacobians;
- a centre-of-mass task moves the body's centre of mass (as pinocchio computes it) to its target at
  the task's rate; a relative task brings the hands together; a posture task pulls untracked joints
  to the posture and leaves tracked ones to their targets;
- a contact, as a stiff task or as equality rows on either backend, holds the foot still while on
  and lets it go while off.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from conftest import human48_walk, random_configurations

from torchik import KinematicModel
from torchik.method import tasks
from torchik.method.constraints import ContactLimit
from torchik.method.kinematics.mass import centre_of_mass
from torchik.method.models import TRACKED_LINKS, human_urdf, icub_urdf_path
from torchik.method.state import State, TargetSequence
from torchik.method.tracker import DynamicalIK
from torchik.pipelines.diagnosis.analysis import sequence_of

LINKS = TRACKED_LINKS["human48"]


def pinocchio_centre_of_mass(path, model: KinematicModel, p, R, s):
    """pinocchio's centre of mass [B,3] and its Jacobian [B,3,6+n], turned to MIXED (pinocchio's
    free flyer's velocity is the base's, in the base frame)."""
    pin = pytest.importorskip("pinocchio")
    reference = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    data = reference.createData()
    joints = [reference.joints[reference.getJointId(name)] for name in model.joint_names]
    positions, jacobians = [], []
    for b in range(p.shape[0]):
        q = np.zeros(reference.nq)
        q[:3], q[3:7] = p[b].numpy(), pin.Quaternion(R[b].numpy()).coeffs()
        for joint, angle in zip(joints, s[b].tolist()):
            q[joint.idx_q] = angle
        positions.append(pin.centerOfMass(reference, data, q))
        J = pin.jacobianCenterOfMass(reference, data, q)
        Rt = R[b].numpy().T
        jacobians.append(np.concatenate((J[:, :3] @ Rt, J[:, 3:6] @ Rt, J[:, [j.idx_v for j in joints]]), 1))
    return np.array(positions), np.array(jacobians)


@pytest.mark.parametrize("name", ["human66", "human48", "icub"])
def test_the_centre_of_mass_and_its_jacobian_equal_pinocchios(name, tmp_path):
    path = icub_urdf_path() if name == "icub" else tmp_path / f"{name}.urdf"
    if name != "icub":
        path.write_text(human_urdf(int(name[-2:])))
    model = KinematicModel.from_urdf(path)
    p, R, s = random_configurations(model, 6, seed=2)
    com = centre_of_mass(model, p, R, s)
    position, jacobian = pinocchio_centre_of_mass(path, model, p, R, s)
    assert np.abs(com.position.numpy() - position).max() <= 1e-12
    assert np.abs(com.jacobian.numpy() - jacobian).max() <= 1e-12


@pytest.fixture(scope="module")
def walk():
    model, urdf, recording = human48_walk(1.0, seed=2, orientation_noise=0.002)
    return model, recording, sequence_of([recording], LINKS)


def test_declaring_the_papers_tasks_is_the_same_tracker(walk):
    model, _, sequence = walk
    plain = DynamicalIK(model, LINKS).run(sequence)
    paper = [tasks.OrientationTask(links=LINKS), tasks.PositionTask(links=(model.base_link,))]
    declared = DynamicalIK(model, tasks=paper).run(sequence)
    assert torch.equal(plain.joint_positions, declared.joint_positions)
    assert torch.equal(plain.base_rotation, declared.base_rotation)


def test_a_task_of_weight_zero_leaves_the_tree_solution_of_a_batch_unchanged(walk):
    model, _, sequence = walk
    x = sequence  # the same walk for 128 subjects: the batched backend solves on the tree from 96
    batch = TargetSequence(x.time, *(v.expand(-1, 128, *v.shape[2:]) for v in
                                     (x.position, x.linear_velocity, x.rotation, x.angular_velocity)))
    tree = DynamicalIK(model, LINKS, backend="batched")
    dense = DynamicalIK(model, LINKS, backend="batched", tasks=[tasks.PostureTask(weight=0.0)])
    assert tree.structure.tree is not None and dense.structure.tree is None
    a, b = tree.run(batch), dense.run(batch)
    assert (a.joint_positions - b.joint_positions).abs().max() <= 1e-10


def test_a_centre_of_mass_task_takes_the_centre_of_mass_to_its_target_at_its_rate(tmp_path):
    path = tmp_path / "human48.urdf"
    path.write_text(human_urdf(48))
    model = KinematicModel.from_urdf(path)
    start = centre_of_mass(model, *model.zero_configuration(1), jacobian=False).position
    target = start + torch.tensor([[0.04, -0.03, 0.0]], dtype=torch.float64)
    gain = 10.0
    # the pelvis' orientation held, its position free: the centre of mass can reach its target exactly
    added = [tasks.CentreOfMassTask(gain, target=target), tasks.PostureTask(weight=1e-4)]
    tracker = DynamicalIK(model, ("Pelvis",), (), tasks=added)
    tracker.reset()
    from torchik.method.targets import Targets

    held = Targets(torch.zeros(1, 0, 3, dtype=torch.float64), torch.zeros(1, 0, 3, dtype=torch.float64),
                   torch.eye(3, dtype=torch.float64)[None, None], torch.zeros(1, 1, 3, dtype=torch.float64))
    distance = []
    for _ in range(60):
        q, _ = tracker.step(held)
        c, _ = pinocchio_centre_of_mass(path, model, q.base_position, q.base_rotation, q.joint_positions)
        distance.append(float(np.linalg.norm((c - target.numpy())[0, :2])))
    # the horizontal distance closes as (1 - K dt)^k, Euler's exp(-K t): from 0.05 m
    for k in (9, 29, 59):
        assert distance[k] == pytest.approx(0.05 * (1 - gain * 0.01) ** (k + 1), rel=0.02, abs=1e-7)


def test_a_relative_task_brings_the_hands_together(walk):
    model, recording, _ = walk
    arms = tuple(n for n in LINKS if "Hand" not in n and "ForeArm" not in n)  # the arms left to the task
    together = tasks.RelativePositionTask(20.0, a="RightHand", b="LeftHand")
    run = DynamicalIK(model, arms, tasks=[together]).run(sequence_of([recording], arms))
    out = model(run.base_position[-1], run.base_rotation[-1], run.joint_positions[-1], ("RightHand", "LeftHand"),
                jacobian=False)
    assert float((out.position[:, 0] - out.position[:, 1]).norm()) <= 0.01


def test_a_posture_task_fills_only_what_no_target_sees(walk):
    model, recording, _ = walk
    untracked = tuple(n for n in LINKS if n not in ("Head", "Neck"))
    sequence = sequence_of([recording], untracked)
    plain = DynamicalIK(model, untracked).run(sequence)
    pulled = DynamicalIK(model, untracked, tasks=[tasks.PostureTask(weight=1e-3)]).run(sequence)
    neck = [k for k, name in enumerate(model.joint_names) if "C1Head" in name or "T1C7" in name]
    assert pulled.joint_positions[-1, 0, neck].abs().max() < 0.5 * plain.joint_positions[-1, 0, neck].abs().max() \
        or plain.joint_positions[-1, 0, neck].abs().max() < 1e-6
    # the tracked links' orientations hardly move: a posture of weight 1e-3 against targets of weight 1
    assert (pulled.joint_positions[:, :, :] - plain.joint_positions).abs()[..., [
        k for k in range(model.n_dof) if k not in neck]].max() <= 0.05


def _foot_slide(model, run, link: str, on: torch.Tensor) -> float:
    """mm: the largest horizontal distance the link's origin travels while `on` [T] holds."""
    out = model(run.base_position[:, 0], run.base_rotation[:, 0], run.joint_positions[:, 0], (link,), jacobian=False)
    p = out.position[:, 0, :2]
    slide, anchor = 0.0, None
    for k in range(len(on)):
        if not on[k]:
            anchor = None
            continue
        anchor = p[k] if anchor is None else anchor
        slide = max(slide, float((p[k] - anchor).norm()))
    return 1e3 * slide


@pytest.mark.parametrize("how", ["task", "equality piqp", "equality batched"])
def test_a_contact_holds_the_foot_still_while_on_and_lets_it_go_while_off(walk, how):
    model, _, sequence = walk
    T = len(sequence.time)
    on = (torch.arange(T) // 25) % 2 == 0  # on a quarter of a second, off the next
    contact = tasks.ContactTask(link="RightFoot", on=on[:, None])
    kw = dict(tasks=[contact]) if how == "task" else dict(constraints=[ContactLimit(contact=contact)])
    if how == "equality batched":
        kw["backend"] = "batched"
    free = DynamicalIK(model, LINKS).run(sequence)
    held = DynamicalIK(model, LINKS, **kw).run(sequence)
    slide = _foot_slide(model, free, "RightFoot", on)
    assert slide > 100.0  # the walk moves the foot by decimetres in a quarter of a second
    # a stiff task of weight 100 against 23 orientation targets of weight 1: under 1 % of that; the
    # equality rows exactly, but for the Euler step's curvature (J nu holds at the step's start; the
    # drift it leaves, O(dt^2), the next step's K corrects): under half a millimetre at 50 Hz
    assert _foot_slide(model, held, "RightFoot", on) <= (0.01 * slide if how == "task" else 0.5)
    assert bool(held.diagnostics["solved"].all())
    # off, the foot goes where the walk takes it
    off = ~on
    out = [model(r.base_position[:, 0], r.base_rotation[:, 0], r.joint_positions[:, 0], ("RightFoot",),
                 jacobian=False).position[:, 0] for r in (free, held)]
    assert float((out[0][off] - out[1][off]).norm(dim=-1).max()) > 0.005


def test_a_relative_tasks_jacobian_is_the_difference_of_idyntrees_frame_jacobians(tmp_path):
    """RelativePositionTask's rows: the velocity of b's origin less a's, as iDynTree's MIXED frame
    Jacobians give them, at random configurations; its residual, the offset less their distance."""
    from test_kinematics import idyntree_reference

    path = tmp_path / "human48.urdf"
    path.write_text(human_urdf(48))
    model = KinematicModel.from_urdf(path)
    p, R, s = random_configurations(model, 4, seed=5)
    offset = torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64)
    task = tasks.RelativePositionTask(a="RightHand", b="LeftHand", offset=offset)
    r, J, _, _ = task.terms(tasks.StepContext(model, State(p, R, s, torch.zeros(4, 6 + model.n_dof, dtype=torch.float64)),
                                        0.01, 0))
    T, J_ref = idyntree_reference(model, path, ("RightHand", "LeftHand"), p, R, s)
    assert np.abs(J.numpy() - (J_ref[:, 1, :3] - J_ref[:, 0, :3])).max() <= 1e-9
    assert np.abs(r.numpy() - (offset.numpy() - (T[:, 1, :3, 3] - T[:, 0, :3, 3]))).max() <= 1e-9
