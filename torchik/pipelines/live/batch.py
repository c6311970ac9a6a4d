"""A tracker whose batch rows are a live session's active characters (`BatchTracker`), and the
robot a session retargets to as it tracks (`LiveRetarget`, `torchik live --retarget icub`)."""

from __future__ import annotations

import torch

from ...errors import InputError
from ...io.maps import load_map
from ...method.kinematics import KinematicModel
from ...method.limits import LimitSettings
from ...method.models import load_model
from ...method.settings import TrackerSettings
from ...method.state import State, StepDiagnostics, Trajectory
from ...method.targets import Targets
from ...method.tracker import DynamicalIK
from ..retarget import LIMIT_TOLERANCE, Retargeted, check_retargeting, icub_tracker, limit_excess, limit_excess_rows
from .targets import Selection, retargeted


def rows_from(targets: Targets, first: int) -> Targets:
    """The targets of batch rows first, first + 1, ... (those of the characters joining)."""
    return Targets(*(t[first:] for t in vars(targets).values()))


class BatchTracker:
    """A DynamicalIK whose rows are the active characters: characters join, from the tracker's
    initial_state of their first targets, and leave. Between joins and departures the batch and
    the tracker's state are left as they are: a step is the tracker's step."""

    def __init__(self, tracker: DynamicalIK):
        self.tracker = tracker
        self.size = 0

    def join(self, targets: Targets) -> None:
        """New rows after the present ones, from their first targets [k,...]."""
        new = self.tracker.initial_state(targets)
        if self.size:
            old = self.tracker.state
            new = State(*(torch.cat((a, b)) for a, b in zip(vars(old).values(), vars(new).values())))
        self.size += targets.batch
        self.tracker.reset(new, batch=self.size)

    def keep(self, rows: torch.Tensor) -> None:
        """Only the rows `rows` [k] (k >= 1) stay, in that order."""
        state = self.tracker.state
        rows = rows.to(state.base_position.device)
        self.size = len(rows)
        self.tracker.reset(State(*(t.index_select(0, rows) for t in vars(state).values())), batch=self.size)

    def step(self, targets: Targets, dt) -> tuple[State, StepDiagnostics]:
        return self.tracker.step(targets, dt)


class LiveRetarget:
    """The robot's side of a live session, as `torchik retarget` does offline: the tracked model's
    targets through the built-in human_to_icub map, tracked by iCub (one row per character, each
    starting, and restarting after a gap, from the whole-body IK fit of its targets), every published sample checked
    against iCub's joint and coupled limits (rows beyond them by more than LIMIT_TOLERANCE are not
    published, and counted)."""

    def __init__(self, gain: float = TrackerSettings.orientation_gain, limits: LimitSettings = LimitSettings(),
                 backend: str = TrackerSettings.backend, device="cpu"):
        self.gain, self.limits, self.backend = gain, limits, backend
        self.model = load_model("icub", device=device)
        self.link_map = load_map("human_to_icub")
        self.selection: Selection | None = None
        self.batch: BatchTracker | None = None
        self.refused = 0
        self.largest_excess = -float("inf")

    def start(self, links, base_link: str, rate: float) -> None:
        """Set up for the tracked model's `links` (its base link `base_link`) at the stream's rate."""
        check_retargeting(rate, self.gain, self.limits)
        if self.link_map.base_segment != base_link:
            raise InputError(f"--retarget: map {self.link_map.name!r} takes the base from {self.link_map.base_segment!r}; "
                             f"the tracked model's base link is {base_link!r}")
        self.selection = Selection.build(links, (), self.link_map)
        # no restart after a gap: a whole-body fit takes longer than the gap it would
        # follow, and the next gap would restart it again; the robot moves on from where it is at its
        # rate limits instead, as its position controller would
        self.batch = BatchTracker(icub_tracker(self.model, self.selection.links, rate, self.gain, self.limits,
                                               self.backend, max_gap=float("inf")))

    def targets(self, tracked: Targets) -> Targets:
        """The robot's targets [B,...] from the tracked model's."""
        assert self.selection is not None  # started
        return retargeted(tracked, self.selection, self.model.dtype, self.model.device)

    def step(self, targets: Targets, dt) -> tuple[State, StepDiagnostics, torch.Tensor]:
        """The robot's step, and which rows [B] are within every limit (to LIMIT_TOLERANCE)."""
        assert self.batch is not None  # started
        state, diagnostics = self.batch.step(targets, dt)
        excess = limit_excess_rows(self.model, state.joint_positions)
        within = excess <= LIMIT_TOLERANCE
        self.refused += int((~within).sum())
        self.largest_excess = max(self.largest_excess, float(excess.max()))
        return state, diagnostics, within

    def report(self) -> dict:
        return dict(robot=self.model.name, limit_excess=self.largest_excess, refused_beyond_limits=self.refused,
                    tolerance=LIMIT_TOLERANCE)


def as_retargeted(trajectory: Trajectory, robot: KinematicModel) -> Retargeted:
    """A character's robot trajectory (B = 1) as `torchik retarget` writes it (mnte: the step's own,
    against the targets of its start)."""
    s = trajectory.joint_positions[:, 0]
    host = lambda x: x.detach().cpu().numpy()  # noqa: E731
    return Retargeted(host(trajectory.time), robot.joint_names, host(s), host(trajectory.velocity[:, 0, 6:]),
                      host(trajectory.base_position[:, 0]), host(trajectory.base_rotation[:, 0]),
                      host(trajectory.diagnostics["mnte"][:, 0]), limit_excess(robot, s))
