"""The experiment's settings and its cases: one model tracking one motion.

The data are one person's: the built-in scenarios generated on Human66 (the full human model),
read by Human66 and Human48 as they are and by iCub through `models/maps/human_to_icub.toml`,
or recordings (through a link map first when their segments are not the human models' links).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from ...errors import InputError
from ...io.maps import apply_map, load_map
from ...io.recording import Recording
from ...method.kinematics import KinematicModel
from ...method.models import MODELS, TRACKED_LINKS, load_model
from ...method.settings import TrackerSettings
from ...synthetic.scenarios import SCENARIOS, scenario
from ..retarget import human_to_icub

PERSON = "human66"  # the model the built-in scenarios are generated on: the person being tracked


@dataclass(frozen=True)
class Settings:
    """duration (s) and rate (Hz) of the built-in scenarios; transient: seconds left out of the
    statistics; gain: K (1/s) of the dynamical method for positions and orientations (the
    tracker's default); backend: the QP backend of every method; tolerance, step_tolerance,
    max_iterations: the instantaneous methods' stopping rule (see WholeBodyIK); threads: torch's
    threads while timing; repeats: runs of each method, each step timed by its fastest; seed;
    convergence_seconds: length of the convergence runs to a static T-pose."""

    duration: float = 10.0
    rate: float = 100.0
    transient: float = 2.0
    gain: float = TrackerSettings.orientation_gain
    backend: str = "batched"
    tolerance: float = 1e-10
    step_tolerance: float = 1e-6
    max_iterations: int = 50
    threads: int = 1
    repeats: int = 2
    seed: int = 0
    convergence_seconds: float = 3.0


@dataclass(frozen=True)
class Case:
    """One model tracking one motion: the recording in the model's link names."""

    model: str
    scenario: str
    recording: Recording
    links: tuple[str, ...]


@lru_cache(maxsize=None)
def cached_model(name: str) -> KinematicModel:
    """The default models, built once (a human model's URDF takes half a second to generate)."""
    return load_model(name)


def scenario_cases(settings: Settings, models=MODELS, scenarios=tuple(SCENARIOS)) -> list[Case]:
    """The built-in scenarios generated on the person (Human66), for each model."""
    person = cached_model(PERSON)
    motions = {name: scenario(name, person, TRACKED_LINKS[PERSON], settings.duration, settings.rate, settings.seed)
               for name in scenarios}
    return [case for name, recording in motions.items() for case in model_cases(name, recording, models)]


def data_cases(paths, models=MODELS, map_name: str | None = None, calibration_frame=None) -> list[Case]:
    """Recordings (any format `torchik track` reads), through `map_name` to the human models'
    links when given, for each model; the scenario is the file's name."""
    from ...io import read

    cases = []
    for path in paths:
        recording = read(str(path))
        if map_name:
            recording = apply_map(recording, load_map(map_name), cached_model(PERSON), calibration_frame)
        cases += model_cases(Path(path).stem, recording, models)
    return cases


def model_cases(name: str, recording: Recording, models) -> list[Case]:
    """`recording` (in the human models' links) for each of `models`: iCub's through the
    human-to-iCub map, the human models' as it is (which needs the Pelvis as base and target)."""
    cases = []
    for model_name in models:
        if model_name == "icub":
            mapped = human_to_icub(recording, cached_model("icub"))
            cases.append(Case(model_name, name, mapped, mapped.links))
            continue
        if recording.base_link != "Pelvis" or "Pelvis" not in recording.links:
            raise InputError(f"{name}: the human models need the Pelvis as base and target; the recording's links "
                             f"are {list(recording.links)} (give --map to convert them)")
        cases.append(Case(model_name, name, recording, recording.links))
    return cases
