"""On a CUDA device the batched tracker runs the same code as on the CPU: the same states to 1e-9
and no joint or coupled limit crossed (skipped where torch sees no CUDA device, as in CI)."""

import pytest
import torch

from torchik.method.models import TRACKED_LINKS, load_model
from torchik.method.state import State, TargetSequence
from torchik.method.tracker import DynamicalIK
from torchik.synthetic.motion import periodic_motion, targets_from_motion

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def on(sequence: TargetSequence, device: str) -> TargetSequence:
    return TargetSequence(*(t.to(device) for t in vars(sequence).values()))


@pytest.mark.parametrize("name", ["human48", "icub"])
def test_a_batch_tracked_on_cuda_gives_the_cpu_states_and_keeps_every_limit(name):
    model, links = load_model(name), TRACKED_LINKS[name]
    free = model.to()  # a copy, for targets from a motion that leaves the joint ranges: the bounds act
    free.lower = torch.full_like(model.lower, -10.0)
    free.upper = torch.full_like(model.upper, 10.0)
    motion = periodic_motion(free, 3.0, 100, batch=32, joint_amplitude=1.2, seed=3)
    sequence = targets_from_motion(free, motion, links)
    p, R = model.zero_configuration(32)[:2]
    s0 = ((model.lower + model.upper) / 2).clamp(-0.3, 0.3).expand(32, -1).clone()
    if name == "icub":  # a start inside the coupled shoulder limits
        s0[:, [model.joint_names.index(j) for j in ("r_shoulder_roll", "l_shoulder_roll")]] = 0.6
    initial = State(p + torch.tensor([0.0, 0.0, 0.9], dtype=torch.float64), R, s0,
                    torch.zeros(32, 6 + model.n_dof, dtype=torch.float64))

    def run(device: str):
        tracker = DynamicalIK(model.to(device=device), links, dt=0.01, backend="batched")
        start = State(*(x.to(device) for x in vars(initial).values()))
        return tracker.run(on(sequence, device), initial=start)

    cpu, gpu = run("cpu"), run("cuda")
    s = gpu.joint_positions.cpu()  # [T,B,n]
    assert float((s - cpu.joint_positions).abs().max()) < 1e-9
    assert float((gpu.base_rotation.cpu() - cpu.base_rotation).abs().max()) < 1e-9
    lower, upper = model.lower, model.upper
    assert float((s - upper).max()) <= 1e-6 and float((lower - s).max()) <= 1e-6
    assert bool((((s - upper).abs() < 1e-3) | ((s - lower).abs() < 1e-3)).any())  # the bounds were reached
    if name == "icub":
        A, b = model.linear_limits.A, model.linear_limits.b
        assert float((s @ A.T - b).max()) <= 1e-6
