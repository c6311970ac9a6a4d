"""Latency of `torchik live`: from a datagram's arrival to the published LSL sample.

For each setting (1 character at 60, 120 and 240 Hz; 8 and 64 characters at 100 Hz) a separate
process replays a generated walk as Xsens MVN streams it (UDP, loopback, in real time), and the
live loop of `torchik live` tracks it (human66, default settings: a burst of up to 8 samples is
tracked in order while a sample costs the loop at most half a frame, else the newest only;
`--backlog 1`: always the newest) and publishes every character's joint positions on an LSL
outlet. Latency: from the moment the datagram that completed a sample was read off the socket to
the return of the LSL push of its estimate (a sample caught up after a burst counts its wait).
Skipped: samples stepped over because the tracker was still busy. The first second is left out
(model set-up, first steps).

Targets (issue 17): 1 character at 240 Hz with p99 <= 2 ms and nothing skipped; 64 characters
at 100 Hz with p99 <= 10 ms.

    python experiments/live_latency.py                       # each setting 60 s, about 6 minutes
    python experiments/live_latency.py --only 1@240 --duration 10      # one setting, quickly
    python experiments/live_latency.py --duration 5 --json live_latency.json

    python experiments/live_latency.py --only 1@240 --compile --warm-up 30 --duration 10
                  # the step replayed compiled; the capture (seconds) falls in the warm-up
    python experiments/live_latency.py --only 64@100 --receiver thread --duration 10
                  # received in a thread of the tracker's process, as before the receiver process
    python experiments/live_latency.py --only 64@100 --compile --step-alone
                  # the tracker's step alone (no live loop, receiver or replay), for comparison

Beside the latency it prints the tracker's step time (median, p99) of the batch, the frames missed
(stepped over or lost) after the warm-up, and the CPU seconds of the tracker's thread (set-up
included), of the receiver (its process, or the tracker process's other threads) and of the
replay: at 64 characters the step itself takes a 100 Hz frame on one core (some 10 ms eager, 8 ms
compiled), which bounds the latency from below.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import time

import numpy as np
import torch

from torchik.live.sample import BACKLOG

SETTINGS = ((1, 60.0), (1, 120.0), (1, 240.0), (8, 100.0), (64, 100.0))  # (characters, rate Hz)
WARM_UP_S = 1.0


def _replay(port: int, characters: int, rate: float, duration: float, cpu, nice: int = 0) -> None:
    """cpu: a shared double, set to the CPU seconds the replay itself took (the walk's generation left
    out); nice: the replay's niceness, raised by this much (a sender that yields its core)."""
    torch.set_num_threads(1)
    os.nice(nice)
    from torchik.live.sample import Url
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.pipelines.replay import replay
    from torchik.synthetic.scenarios import scenario

    walk = scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=duration, rate=rate)
    start = time.process_time()
    replay(walk, Url("udp", "127.0.0.1", port), characters=characters, lead_in_s=0.5)
    cpu.value = time.process_time() - start


def measure(characters: int, rate: float, duration: float, receiver: str = "process", compile: bool = False,
            warm_up: float = WARM_UP_S, backlog: int | None = None, replay_nice: int = 0) -> dict:
    """One setting's latency, skips and step times after `warm_up` s, and the CPU seconds of the
    tracker's thread (set-up included), the receiver (its process from its first datagram, or the
    other threads of the tracker's process) and the replay (streaming only)."""
    from torchik.live.sources import open_source
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.method.settings import TrackerSettings
    from torchik.pipelines.live import LiveOptions, Publisher, Selection, track_live

    model = load_model("human66")
    links = TRACKED_LINKS["human66"]
    source = open_source("udp://127.0.0.1:0", receiver_process=receiver == "process", backlog=backlog)
    context = multiprocessing.get_context("spawn")
    replay_cpu = context.Value("d", float("nan"))
    sender = context.Process(target=_replay, args=(source.address[1], characters, rate, duration + warm_up, replay_cpu,
                                                      replay_nice))
    sender.start()
    publisher = Publisher(f"torchik-latency-{characters}-{rate:g}", model, rate=rate)
    thread_start, process_start = time.thread_time(), time.process_time()
    result = track_live(source, model, lambda names: Selection.build(names, links), TrackerSettings(compile=compile),
                        publisher=publisher, options=LiveOptions(backlog=backlog, stop_when_idle_s=1.0, keep_states=False))
    tracker_cpu, process_cpu = time.thread_time() - thread_start, time.process_time() - process_start
    sender.join()
    kept = lambda values: values[int(len(values) * warm_up / (duration + warm_up)):]  # noqa: E731
    # the warm-up's share of the published samples left out (by count, not by frames: samples the
    # tracker stepped over were never published, so the frame count would leave out too many)
    latency = kept(result.latency) * 1e3
    steps = kept(result.step_time) * 1e3
    return dict(characters=characters, rate_hz=rate, duration_s=duration, receiver=receiver, compile=compile,
                backlog=backlog, replay_nice=replay_nice, published=int(len(result.latency)),
                samples=result.source_stats["samples"],
                skipped=sum(result.skipped.values()), missed_after_warm_up=_missed(result, warm_up),
                lost=result.source_stats["lost"],
                latency_ms=dict(p50=float(np.median(latency)), p99=float(np.quantile(latency, 0.99)),
                                max=float(latency.max())) if len(latency) else None,
                step_ms_median=float(np.median(steps)) if len(steps) else None,
                step_ms_p99=float(np.quantile(steps, 0.99)) if len(steps) else None,
                cpu_s=dict(tracker_thread=tracker_cpu, replay=replay_cpu.value,
                           receiver=getattr(source, "serving_cpu_s", None) or process_cpu - tracker_cpu))


def step_alone(characters: int, rate: float, duration: float, compile: bool = False, steps: int = 2500) -> dict:
    """The tracker's step without the live loop around it: the same walk, each character offset in
    phase as the replay offsets it, stepped `steps` times as one batch in this process alone; the
    step's median and p99 (ms, after 10 steps, the capture among them) and the share of steps with
    a bound active for some character (such a step runs the backend's solve)."""
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.method.state import State
    from torchik.method.targets import Targets
    from torchik.method.tracker import DynamicalIK
    from torchik.synthetic.motion import targets_from_motion
    from torchik.synthetic.scenarios import scenario_motion

    model, links = load_model("human66"), TRACKED_LINKS["human66"]
    motion = scenario_motion("walking", model, duration, rate)
    T = len(motion.time)
    offsets = torch.tensor([c * T // characters for c in range(characters)])
    walk = targets_from_motion(model, motion, links)
    fields = ("position", "linear_velocity", "rotation", "angular_velocity")
    at = lambda k: Targets(*(getattr(walk, f)[(k + offsets) % T, 0] for f in fields))  # noqa: E731
    tracker = DynamicalIK(model, links, dt=1 / rate, compile=compile)
    tracker.reset(State(motion.base_position[offsets, 0], motion.base_rotation[offsets, 0],
                        motion.joint_positions[offsets, 0], motion.velocity[offsets, 0]), batch=characters)
    times, active = [], []
    for k in range(10 + steps):
        start = time.perf_counter()
        _, diagnostics = tracker.step(at(k))
        times.append(time.perf_counter() - start)
        active.append(bool((diagnostics.active_constraints > 0).any()))
    ms = 1e3 * np.array(times[10:])
    return dict(characters=characters, rate_hz=rate, compile=compile, steps=steps, step_ms_median=float(np.median(ms)),
                step_ms_p99=float(np.quantile(ms, 0.99)), active_share=float(np.mean(active[10:])))


def _missed(result, warm_up: float) -> int:
    """Frames not stepped to after the warm-up (stepped over or lost), from every character's steps."""
    missed = 0
    for time_s, _ in result.characters.values():
        frames = np.round(time_s.numpy() * result.rate).astype(np.int64)
        after = frames[frames >= frames[0] + warm_up * result.rate]
        missed += int((np.diff(after) - 1).sum()) if len(after) > 1 else 0
    return missed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per setting (default 60)")
    parser.add_argument("--only", metavar="N@HZ", action="append",
                        help="run only these settings, e.g. --only 1@240 --only 64@100")
    parser.add_argument("--json", metavar="FILE", help="write the results here")
    parser.add_argument("--receiver", choices=("process", "thread"), default="process",
                        help="receive in a process of its own (default, as torchik live) or in a thread")
    parser.add_argument("--compile", action="store_true", help="the tracker's step replayed compiled, as torchik "
                        "live --compile (captured at the third step: give --warm-up the seconds this takes)")
    parser.add_argument("--backlog", type=int, metavar="N", help="samples queued per character, all tracked in "
                        f"order, as torchik live --backlog (1: the newest; default: up to {BACKLOG}, caught up while "
                        "the step takes at most half a frame)")
    parser.add_argument("--warm-up", type=float, default=WARM_UP_S, metavar="S",
                        help=f"seconds left out at the start (default {WARM_UP_S:g})")
    parser.add_argument("--replay-nice", type=int, default=0, metavar="N",
                        help="raise the replay's niceness by N (e.g. 19: the sender yields its core to the receiver "
                             "and the tracker, as a sender on another machine would not compete for them)")
    parser.add_argument("--step-alone", action="store_true",
                        help="instead: the tracker's step alone, without the live loop, the receiver or the replay "
                             "(the same walks as one batch, 2 500 steps): what the live loop's step time is up against")
    args = parser.parse_args()
    # one intra-op thread: the per-step tensors are small, and a second thread would only compete
    # with the receiver and the replay for the two cores of the machine this was written on
    torch.set_num_threads(1)
    settings = SETTINGS if not args.only else [(int(n), float(hz)) for n, hz in (s.split("@") for s in args.only)]
    results = []
    for characters, rate in settings:
        if args.step_alone:
            r = step_alone(characters, rate, args.duration + args.warm_up, args.compile)
            results.append(r)
            print(f"{characters:3d} character(s) at {rate:5.0f} Hz, the step alone: median {r['step_ms_median']:.2f} ms, "
                  f"p99 {r['step_ms_p99']:.2f} ms; a bound active on {100 * r['active_share']:.1f} % of the steps",
                  flush=True)
            continue
        r = measure(characters, rate, args.duration, args.receiver, args.compile, args.warm_up, args.backlog,
                    args.replay_nice)
        results.append(r)
        lat, cpu = r["latency_ms"] or {}, r["cpu_s"]
        print(f"{characters:3d} character(s) at {rate:5.0f} Hz: latency p50 {lat.get('p50', float('nan')):6.2f} ms, "
              f"p99 {lat.get('p99', float('nan')):6.2f} ms, max {lat.get('max', float('nan')):7.2f} ms; "
              f"skipped {r['skipped']} of {r['samples']} samples ({r['missed_after_warm_up']} frames missed after "
              f"the warm-up); step median {r['step_ms_median']:.2f} ms, p99 {r['step_ms_p99']:.2f} ms; CPU s: "
              f"tracker {cpu['tracker_thread']:.1f}, receiver {cpu['receiver']:.1f}, replay {cpu['replay']:.1f}",
              flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(machine=platform.processor() or platform.machine(), cpus=torch.get_num_threads(),
                           time=time.strftime("%Y-%m-%dT%H:%M:%S"), results=results), f, indent=2)


if __name__ == "__main__":
    main()
