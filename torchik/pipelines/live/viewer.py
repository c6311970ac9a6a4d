"""The live viewer of `torchik live --viewer` and `--rrd FILE`: the session's steps as a rerun
recording, streamed to a viewer (spawned, or one at a rerun+http:// URL) and/or saved to a file,
with the entities of `track --rrd` (`StepLogger`, torchik/pipelines/rrd.py) and the live counters
as scalars (/live/<counter>).

Logging a step (the link poses' kinematics, a hundred or so entities per character) holds the
GIL for milliseconds per character: in the tracking process it would stall every torch call of
the tracker waiting for it. So the logging runs in a process of its own: the loop offers its newest
step (`offer`), at most `rate` times a second it is converted to arrays and queued (a queue of
two: when the logger falls behind, steps are left out and counted, never waited for), and the
logger process draws them."""

from __future__ import annotations

import contextlib
import multiprocessing
import queue
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ...errors import InputError, optional
from ...io.files import replacing
from ...method.kinematics import KinematicModel
from ...method.state import PER_BATCH, PER_SUBJECT, TargetSequence, Trajectory
from ..visuals import Visual

COUNTERS = ("datagrams", "samples", "skipped", "lost", "late", "duplicates", "malformed", "incomplete", "stalls",
            "characters")  # the live counters logged at /live/<name>; datagrams: received
VIEWER_PORT = 9876  # rerun's default


def viewer_url(text: str) -> str:
    """A rerun viewer's gRPC URL as rerun takes it (rerun+http://HOST:PORT/proxy, rerun://...,
    rerun+https://...); InputError saying what one looks like."""
    if not text.startswith(("rerun://", "rerun+http://", "rerun+https://")) or not text.rstrip("/").endswith("/proxy"):
        raise InputError(f"--viewer {text!r}: expected a rerun viewer's URL, e.g. rerun+http://127.0.0.1:9876/proxy")
    return text


@dataclass(frozen=True)
class ViewerSpec:
    """What the logger process needs: the tracked model (on the CPU: the logger computes the link
    poses) and its tracked links, the visuals that draw the body (`visuals(urdf)`), and where to
    send: spawn a viewer on `port`, connect to `url`, save to `path`."""

    model: KinematicModel
    links: tuple[str, ...]
    shapes: dict[str, list[Visual]]
    spawn: bool = False
    url: str | None = None
    path: str | None = None
    port: int = VIEWER_PORT


class LiveViewer:
    """The logger process and its queue. rate: most snapshots a second (the display's rate)."""

    def __init__(self, spec: ViewerSpec, rate: float = 30.0):
        optional("rerun", "viz", "a live viewer")  # missing rerun: said before the session starts
        if not rate > 0:
            raise InputError(f"--viewer-rate {rate}: must be positive")
        self.period = 1.0 / rate
        self.sent = self.left_out = 0
        self._last = -float("inf")
        self._files = contextlib.ExitStack()
        part = None if spec.path is None else str(self._files.enter_context(replacing(spec.path)))
        context = multiprocessing.get_context("spawn")  # fork would copy the tracker's threads' locks
        self._queue = context.Queue(maxsize=2)
        self._process = context.Process(target=_serve, args=(self._queue, spec, part), daemon=True,
                                        name="torchik-live-viewer")
        self._process.start()

    def due(self) -> bool:
        """Whether a display period has passed since the last step offered (then the next is)."""
        now = time.perf_counter()
        if now - self._last < self.period:
            return False
        self._last = now
        return True

    def offer(self, snapshot: dict) -> None:
        """A step (time, characters [B], state, diagnostics, targets, counters: a function), queued
        unless the logger is behind. The loop offers one when `due()`."""
        try:
            self._queue.put_nowait(_arrays(snapshot))
            self.sent += 1
        except queue.Full:
            self.left_out += 1

    def close(self, counters: dict | None = None, wait_s: float = 60.0) -> None:
        """Send the last counters, end the logger process (waiting up to `wait_s` for it to log what
        is queued: it may still be starting) and move the file into place."""
        deadline = time.perf_counter() + wait_s
        items = ([dict(final=True, counters=_numbers(counters))] if counters is not None else []) + [None]
        for item in items:
            while self._process.is_alive() and time.perf_counter() < deadline:  # a dead logger takes nothing
                try:
                    self._queue.put(item, timeout=0.2)
                    break
                except queue.Full:
                    continue
        self._process.join(timeout=max(deadline - time.perf_counter(), 0.01))
        if self._process.is_alive():  # stuck (a viewer that never answers): the file may lack its end
            self._process.terminate()
        with contextlib.suppress(FileNotFoundError):  # the logger died before writing: no file to move
            self._files.close()


def _numbers(counters: dict) -> dict[str, float]:
    return {name: float(counters[name]) for name in COUNTERS if counters.get(name) is not None}


def _arrays(snapshot: dict) -> dict:
    """A step as host arrays (what crosses to the logger process)."""
    host = lambda t: t.detach().to("cpu").numpy()  # noqa: E731
    diagnostics = snapshot["diagnostics"]
    return dict(time=snapshot["time"], characters=snapshot["characters"],
                state={name: host(t) for name, t in vars(snapshot["state"]).items()},
                per_subject={name: host(getattr(diagnostics, name)) for name in PER_SUBJECT},
                per_batch={name: float(getattr(diagnostics, name)) for name in PER_BATCH},
                targets={name: host(t) for name, t in vars(snapshot["targets"]).items()},
                counters=_numbers(snapshot["counters"]()))


def _serve(steps, spec: ViewerSpec, part: str | None) -> None:
    """The logger process: sinks opened, then every queued step logged until None comes."""
    import rerun as rr

    from ..rrd import StepLogger, blueprint

    torch.set_num_threads(1)
    rec = rr.RecordingStream("torchik", recording_id=uuid.uuid4())
    sinks: list = []
    if spec.spawn:
        rec.spawn(port=spec.port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{spec.port}/proxy"))
    if spec.url is not None:
        sinks.append(rr.GrpcSink(spec.url))
    if part is not None:
        sinks.append(rr.FileSink(part))
        rec.send_recording_name(Path(spec.path or part).stem)
    rec.set_sinks(*sinks)
    logger = StepLogger(rec, spec.model, spec.links, shapes=spec.shapes)
    laid_out, last = False, 0.0
    while (step := steps.get()) is not None:
        last = step.get("time", last)  # the final counters: at the last step's time
        rec.set_time("time", duration=last)
        if not step.get("final"):
            if not laid_out:  # the layout, on the first character's plots
                rec.send_blueprint(blueprint([int(step["characters"][0])], aggregate=len(step["characters"]) > 1,
                                             live=True))
                laid_out = True
            logger.log(*_trajectory(step), [int(c) for c in step["characters"]])
        for name, value in step["counters"].items():
            rec.log(f"/live/{name}", rr.Scalars(value))
    rec.flush()
    rec.disconnect()


def _trajectory(step: dict) -> tuple[Trajectory, TargetSequence]:
    """One step as a trajectory and targets of T = 1."""
    one = lambda a: torch.from_numpy(np.asarray(a))[None]  # noqa: E731
    time = torch.tensor([step["time"]], dtype=torch.float64)
    s, x = step["state"], step["targets"]
    diagnostics = {name: one(v) for name, v in step["per_subject"].items()}
    diagnostics.update({name: torch.tensor([v], dtype=torch.float64) for name, v in step["per_batch"].items()})
    trajectory = Trajectory(time, one(s["base_position"]), one(s["base_rotation"]), one(s["joint_positions"]),
                            one(s["velocity"]), diagnostics)
    return trajectory, TargetSequence(time, one(x["position"]), one(x["linear_velocity"]), one(x["rotation"]),
                                      one(x["angular_velocity"]))
