"""kinematics: poses and mixed-representation Jacobians agree with iDynTree and with finite differences."""

import numpy as np
import pytest
import torch
from conftest import random_configurations

from torchik import InputError, KinematicModel, ModelError, UnknownLinkError, so3
from torchik.method.models import TRACKED_LINKS, icub_urdf_path, load_model

MODELS = ["human66", "human48", "icub"]


def idyntree_reference(model: KinematicModel, urdf_path, links, p, R, s):
    """Poses [B,L,4,4] and MIXED free-floating Jacobians [B,L,6,6+n] from iDynTree KinDynComputations."""
    idt = pytest.importorskip("idyntree.bindings")
    loader = idt.ModelLoader()
    assert loader.loadReducedModelFromFile(str(urdf_path), list(model.joint_names))
    kd = idt.KinDynComputations()
    assert kd.loadRobotModel(loader.model())
    kd.setFrameVelocityRepresentation(idt.MIXED_REPRESENTATION)
    assert kd.setFloatingBase(model.base_link)
    B, n = s.shape
    T = np.zeros((B, len(links), 4, 4))
    J = np.zeros((B, len(links), 6, 6 + n))
    Jb = idt.MatrixDynSize(6, 6 + n)
    for b in range(B):
        H = np.eye(4)
        H[:3, :3], H[:3, 3] = R[b].numpy(), p[b].numpy()
        kd.setRobotState(H, s[b].numpy(), np.zeros(6), np.zeros(n), np.array([0.0, 0.0, -9.81]))
        for i, link in enumerate(links):
            T[b, i] = kd.getWorldTransform(link).asHomogeneousTransform().toNumPy()
            assert kd.getFrameFreeFloatingJacobian(link, Jb)
            J[b, i] = Jb.toNumPy()
    return T, J


@pytest.fixture(scope="module", params=MODELS)
def model_and_urdf(request, tmp_path_factory):
    name = request.param
    if name == "icub":
        return load_model(name), icub_urdf_path(), TRACKED_LINKS[name]
    from torchik.method.models import human_urdf

    path = tmp_path_factory.mktemp(name) / f"{name}.urdf"
    path.write_text(human_urdf(int(name[-2:])))
    links = TRACKED_LINKS[name] + ("RightHandCOM",)  # a link fixed to a segment, too
    return KinematicModel.from_urdf(path), path, links


@pytest.mark.parametrize("batch", [50, 5])  # 50 composes level by level, 5 by pointer jumping
def test_poses_and_jacobians_match_idyntree(model_and_urdf, batch):
    model, path, links = model_and_urdf
    p, R, s = random_configurations(model, batch, seed=batch)
    out = model(p, R, s, links)
    T, J = idyntree_reference(model, path, links, p, R, s)
    assert np.abs(out.rotation.numpy() - T[..., :3, :3]).max() <= 1e-9
    assert np.abs(out.position.numpy() - T[..., :3, 3]).max() <= 1e-9
    assert np.abs(out.jacobian.numpy() - J).max() <= 1e-9


@pytest.mark.parametrize("batch", [50, 5])  # level by level on SoA, pointer jumping batch-first
def test_rotation_only_kinematics_match_idyntree(model_and_urdf, batch):
    """`rotations`: the link rotations iDynTree gives, and every joint's world axis equal to the
    angular part of iDynTree's Jacobian column of that joint, for any link the joint moves."""
    model, path, links = model_and_urdf
    p, R, s = random_configurations(model, batch, seed=batch + 1)
    out = model.rotations(R, s, links, joint_axes=True)
    assert out.position is None and out.jacobian is None
    T, J = idyntree_reference(model, path, links, p, R, s)
    assert np.abs(out.rotation.numpy() - T[..., :3, :3]).max() <= 1e-9
    mask = model.select(links).ancestor_mask  # [L,n]
    moved = mask.sum(0) > 0
    link_of_joint = mask.argmax(0)  # a link each joint moves (where it moves one)
    columns = J[:, link_of_joint.numpy(), 3:6, 6:]  # [B,n,3,n]: joint j's row holds a link it moves
    axes_from_jacobian = np.diagonal(columns, axis1=1, axis2=3).transpose(0, 2, 1)  # [B,n,3]
    assert np.abs(out.joint_axes.numpy()[:, moved] - axes_from_jacobian[:, moved.numpy()]).max() <= 1e-9


@pytest.mark.parametrize("batch", [50, 5])
def test_a_non_finite_joint_angle_spoils_only_the_links_it_moves(batch):
    """NaN in one joint of one subject: in `rotations`, as in `forward`, exactly the links below that
    joint of that subject are NaN; the other links and subjects are untouched."""
    model = load_model("human48")
    links = TRACKED_LINKS["human48"]
    p, R, s = random_configurations(model, batch, seed=2)
    mask = model.select(links).ancestor_mask  # [L,n]
    for joint in (0, model.joint_names.index("jRightElbow_rotz")):
        bad = s.clone()
        bad[1, joint] = float("nan")
        spoiled = torch.zeros(batch, len(links), dtype=torch.bool)
        spoiled[1] = mask[:, joint] > 0
        for out in (model.rotations(R, bad, links).rotation, model(p, R, bad, links, jacobian=False).rotation):
            assert torch.equal(out.isnan().flatten(-2).any(-1), spoiled)


@pytest.mark.parametrize("name", MODELS)
def test_jacobian_matches_finite_differences(name):
    """Each column of J is the link's (linear, world angular) velocity for a unit component of nu."""
    model = load_model(name)
    links = TRACKED_LINKS[name]
    p, R, s = random_configurations(model, 3, seed=7)
    J = model(p, R, s, links).jacobian
    n, eps = model.n_dof, 1e-6
    cols = []
    for k in range(6 + n):
        def moved(sign, k=k):
            dp, dR, ds = torch.zeros_like(p), torch.eye(3, dtype=p.dtype).expand_as(R), torch.zeros_like(s)
            if k < 3:
                dp = dp.clone()
                dp[:, k] = sign * eps
            elif k < 6:
                w = torch.zeros(3, dtype=p.dtype)
                w[k - 3] = sign * eps
                dR = so3.exp(w).expand_as(R)  # world-frame angular velocity: R <- exp(w) R
            else:
                ds = ds.clone()
                ds[:, k - 6] = sign * eps
            return model(p + dp, dR @ R, s + ds, links, jacobian=False)
        plus, minus = moved(1.0), moved(-1.0)
        v = (plus.position - minus.position) / (2 * eps)
        turn = plus.rotation @ minus.rotation.transpose(-1, -2)
        w = so3.vee(turn - turn.transpose(-1, -2)) / (4 * eps)
        cols.append(torch.cat([v, w], dim=-1))
    J_fd = torch.stack(cols, dim=-1)
    assert (J - J_fd).abs().max() < 1e-7


def test_batch_of_different_subjects_equals_separate_calls():
    from torchik.method.models import HumanSubject

    subjects = [HumanSubject(height=h, mass=60 + 10 * i) for i, h in enumerate((1.55, 1.68, 1.80, 1.95))]
    models = [load_model("human66", subject) for subject in subjects]
    stacked = KinematicModel.stack(models)
    p, R, s = random_configurations(models[0], 4, seed=3)
    links = TRACKED_LINKS["human66"]
    together = stacked(p, R, s, links)
    rotations = stacked.rotations(R, s, links, joint_axes=True)
    for b, m in enumerate(models):
        alone = m(p[b:b + 1], R[b:b + 1], s[b:b + 1], links, joint_axes=True)
        assert torch.allclose(together.position[b], alone.position[0], atol=1e-14)
        assert torch.allclose(together.jacobian[b], alone.jacobian[0], atol=1e-14)
        assert torch.allclose(rotations.rotation[b], alone.rotation[0], atol=1e-14)
        assert torch.allclose(rotations.joint_axes[b], alone.joint_axes[0], atol=1e-14)
    # the subjects really differ: the head is higher for a taller subject at the zero configuration
    p0, R0, s0 = stacked.zero_configuration(4)
    heads = stacked(p0, R0, s0, ["Head"], jacobian=False).position[:, 0, 2]
    assert bool((heads[1:] > heads[:-1]).all())


def test_out_buffers_give_the_same_result_as_fresh_ones():
    model = load_model("human66")
    links = TRACKED_LINKS["human66"]
    buffers = model.empty_output(40, links)
    for seed in (0, 1):  # the second call overwrites the first's values everywhere they can change
        p, R, s = random_configurations(model, 40, seed=seed)
        fresh = model(p, R, s, links)
        reused = model(p, R, s, links, out=buffers)
        assert reused.jacobian is buffers.jacobian
        assert torch.equal(fresh.jacobian, reused.jacobian) and torch.equal(fresh.rotation, reused.rotation)


def test_float32_agrees_with_float64():
    model = load_model("human66")
    model32 = model.to(dtype=torch.float32)
    p, R, s = random_configurations(model, 16, seed=5)
    links = TRACKED_LINKS["human66"]
    a = model(p, R, s, links)
    b = model32(p.float(), R.float(), s.float(), links)
    assert b.jacobian.dtype == torch.float32
    assert (a.position - b.position.double()).abs().max() < 1e-5
    assert (a.jacobian - b.jacobian.double()).abs().max() < 1e-5


def test_bad_input_says_what_was_expected(tmp_path):
    model = load_model("human48")
    p, R, s = random_configurations(model, 2, seed=0)
    with pytest.raises(UnknownLinkError, match="valid links: Pelvis"):
        model(p, R, s, ["Pelvis", "Tail"])
    with pytest.raises(InputError, match=r"joint_positions: expected shape \[2, 48\], got \[2, 47\]"):
        model(p, R, s[:, :47], ["Pelvis"])
    with pytest.raises(InputError, match="expected dtype torch.float64"):
        model(p.float(), R.float(), s.float(), ["Pelvis"])
    with pytest.raises(InputError, match="base_rotation"):
        model(p, R[:, :2], s, ["Pelvis"])
    with pytest.raises(ModelError, match="not found"):
        KinematicModel.from_urdf(tmp_path / "missing.urdf")
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'/><joint name='j' type='revolute'><parent link='a'/>")
    with pytest.raises(ModelError, match="broken.urdf: not a valid URDF"):
        KinematicModel.from_urdf(broken)
    two_parents = tmp_path / "loop.urdf"
    two_parents.write_text(
        "<robot name='x'><link name='a'/><link name='b'/><link name='c'/>"
        "<joint name='j1' type='fixed'><parent link='a'/><child link='c'/></joint>"
        "<joint name='j2' type='fixed'><parent link='b'/><child link='c'/></joint></robot>")
    with pytest.raises(ModelError, match="two parent joints"):
        KinematicModel.from_urdf(two_parents)


def test_the_parser_loaded_alone_reads_the_models_as_pytorch_kinematics_does():
    """The URDF parser loaded without pytorch-kinematics' package (urdf.urdf_class) leaves the package
    and matplotlib unimported, and gives the same trees as the parser imported through the package."""
    import pickle
    import subprocess
    import sys

    code = ("import pickle, sys\nfrom torchik.method.kinematics.urdf import load_tree\n"
            "from torchik.method.models import human_urdf, icub_urdf_path\n"
            "trees = [load_tree(human_urdf(48, None)), load_tree(human_urdf(66, None)), load_tree(icub_urdf_path())]\n"
            "assert 'pytorch_kinematics' not in sys.modules and 'matplotlib' not in sys.modules, 'imported'\n"
            "sys.stdout.buffer.write(pickle.dumps([t.__getstate__() for t in trees]))\n")
    alone = pickle.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, check=True).stdout)
    import pytorch_kinematics  # noqa: F401  (from here on, the package's own parser)

    from torchik.method.kinematics import urdf
    from torchik.method.models import human_urdf, icub_urdf_path

    urdf.urdf_class.cache_clear()
    try:
        assert urdf.urdf_class().__module__ == "pytorch_kinematics.urdf_parser_py.urdf"
        trees = [urdf.load_tree(human_urdf(48, None)), urdf.load_tree(human_urdf(66, None)),
                 urdf.load_tree(icub_urdf_path())]
    finally:
        urdf.urdf_class.cache_clear()
    for a, tree in zip(alone, trees):
        b = tree.__getstate__()
        assert a.keys() == b.keys()
        for key in a:
            if isinstance(a[key], np.ndarray):
                assert np.array_equal(a[key], b[key]), key
            else:
                assert a[key] == b[key], key


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    model = load_model("icub")
    p, R, s = random_configurations(model, 64, seed=9)
    links = TRACKED_LINKS["icub"]
    cpu = model(p, R, s, links)
    gpu = model.to(device="cuda")(p.cuda(), R.cuda(), s.cuda(), links)
    assert (gpu.jacobian.cpu() - cpu.jacobian).abs().max() < 1e-12
