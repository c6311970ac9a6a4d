"""Where a live session's estimates go as they are made: one LSL outlet per character
(`Publisher`), the values of the whole batch converted to one array per step."""

from __future__ import annotations

import time

import numpy as np
import torch

from ...method.kinematics import KinematicModel
from ...method.state import State
from ..visuals import quaternion_xyzw


class Publisher:
    """Each character's joint positions (optionally the base pose and the joint velocities) on its
    own LSL outlet: NAME for character 0, NAME-c for the others. model: whose joints (the tracked
    model's, or the robot's when retargeting)."""

    def __init__(self, name: str, model: KinematicModel, base: bool = False, velocities: bool = False,
                 rate: float | None = None):
        self.name, self.model, self.base, self.velocities = name, model, base, velocities
        self.rate = rate  # the stream's, set by the live loop when it knows it
        self.outlets: dict = {}

    def outlet(self, character: int):
        """The character's outlet, opened on first use: open one ahead to let a recorder connect
        before the first estimate."""
        from ...live.lsl import JointOutlet

        if character not in self.outlets:
            self.outlets[character] = JointOutlet(f"{self.name}-{character}" if character else self.name,
                                                  self.model.joint_names, self.rate or 0.0, character, self.base,
                                                  self.velocities)
        return self.outlets[character]

    def values(self, state: State, rows: torch.Tensor | None) -> np.ndarray:
        """The published channels [m,C] of the batch rows `rows` (None: all), in one conversion."""
        parts = [state.joint_positions]
        if self.base:
            parts += [state.base_position, quaternion_xyzw(state.base_rotation)[:, [3, 0, 1, 2]]]
        if self.velocities:
            parts.append(state.velocity[:, 6:])
        values = torch.cat(parts, dim=1)
        if rows is not None:
            values = values.index_select(0, rows.to(values.device))
        return values.to("cpu", torch.float64).numpy()

    def publish(self, characters, values: np.ndarray, stamps: np.ndarray) -> np.ndarray:
        """values [m,C] of `characters` [m] with their time stamps [m]; returns when each push
        returned (time.perf_counter(), [m]). One outlet per character: a push each."""
        done = np.empty(len(values))
        for k, (character, stamp) in enumerate(zip(characters, stamps.tolist())):
            self.outlet(character).push(values[k:k + 1], stamp)
            done[k] = time.perf_counter()
        return done

