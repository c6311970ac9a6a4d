"""A live session's history (torchik/pipelines/live/history.py): steps kept as batched rows, the
rows of the characters that had a sample; each character's trajectory cut from them holds its own
rows, in order, at its own frames, whichever characters joined, left or missed a step."""

from __future__ import annotations

import numpy as np
import torch

from torchik.method.state import PER_SUBJECT, State, StepDiagnostics
from torchik.pipelines.live.history import History


def step(values: list[float], n: int = 2) -> tuple[State, StepDiagnostics]:
    """A batch whose row b holds values[b] everywhere (joints, base, diagnostics)."""
    v = torch.tensor(values, dtype=torch.float64)
    B = len(values)
    state = State(v[:, None].expand(B, 3).clone(), torch.eye(3, dtype=torch.float64).expand(B, 3, 3).clone(),
                  v[:, None].expand(B, n).clone(), v[:, None].expand(B, 6 + n).clone())
    per_subject = {name: v.clone() for name in PER_SUBJECT}
    per_subject["residual_norm"] = v[:, None].expand(B, 4).clone()
    return state, StepDiagnostics(**per_subject, step_time=1e-3)


def test_each_character_gets_its_own_rows_at_its_own_frames():
    history = History(keep_states=True)
    # step 1: characters 7 and 3 (rows 0, 1); step 2: only 3 had a sample; step 3: 3 and 9 (7 left)
    history.add(np.array([7, 3]), np.array([10, 20]), None, *step([1.0, 2.0]))
    history.add(np.array([3]), np.array([21]), torch.tensor([1]), *step([5.0, 6.0]))
    history.add(np.array([3, 9]), np.array([23, 0]), None, *step([8.0, 9.0]))
    trajectories = history.trajectories(rate=10.0, interrupted=False)
    assert sorted(trajectories) == [3, 7, 9]
    three = trajectories[3]
    np.testing.assert_allclose(three.time.numpy(), [2.0, 2.1, 2.3])
    np.testing.assert_allclose(three.joint_positions[:, 0, 0].numpy(), [2.0, 6.0, 8.0])
    np.testing.assert_allclose(three.diagnostics["mnte"][:, 0].numpy(), [2.0, 6.0, 8.0])
    assert three.joint_positions.shape == (3, 1, 2) and three.diagnostics["residual_norm"].shape == (3, 1, 4)
    np.testing.assert_allclose(trajectories[7].joint_positions[:, 0, 0].numpy(), [1.0])
    np.testing.assert_allclose(trajectories[9].time.numpy(), [0.0])


def test_without_the_states_only_what_the_report_needs_is_kept():
    history = History(keep_states=False)
    history.add(np.array([0, 1]), np.array([0, 0]), None, *step([1.0, 2.0]))
    assert set(history.columns) == {"mnte", "dropped"} and history.trajectories(100.0, False) == {}
    time, columns = history.per_character(100.0)[1]
    assert time.tolist() == [0.0] and columns["mnte"].tolist() == [2.0]
