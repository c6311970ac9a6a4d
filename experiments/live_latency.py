"""Latency of `torchik live`: from a datagram's arrival to the published LSL sample.

For each setting (1 character at 60, 120 and 240 Hz; 8 and 64 characters at 100 Hz) a separate
process replays a generated walk as Xsens MVN streams it (UDP, loopback, in real time), and the
live loop of `torchik live` tracks it (human66, default settings, backlog 1: always the newest
sample) and publishes every character's joint positions on an LSL outlet. Latency: from the
moment the datagram that completed a sample was read off the socket to the return of the LSL
push of its estimate. Skipped: samples stepped over because the tracker was still busy. The
first second is left out (model set-up, first steps).

Targets (issue 17): 1 character at 240 Hz with p99 <= 2 ms and nothing skipped; 64 characters
at 100 Hz with p99 <= 10 ms.

    python experiments/live_latency.py                       # each setting 60 s, about 6 minutes
    python experiments/live_latency.py --only 1@240 --duration 10      # one setting, quickly
    python experiments/live_latency.py --duration 5 --json live_latency.json

Beside the latency it prints the tracker's step time (median, p99) of the batch: at 64 characters
the step itself takes most of a 100 Hz frame on one core, which bounds the latency from below.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import platform
import time

import numpy as np
import torch

SETTINGS = ((1, 60.0), (1, 120.0), (1, 240.0), (8, 100.0), (64, 100.0))  # (characters, rate Hz)
WARM_UP_S = 1.0


def _replay(port: int, characters: int, rate: float, duration: float) -> None:
    torch.set_num_threads(1)
    from torchik.live.sample import Url
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.pipelines.replay import replay
    from torchik.synthetic.scenarios import scenario

    walk = scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=duration, rate=rate)
    replay(walk, Url("udp", "127.0.0.1", port), characters=characters, lead_in_s=0.5)


def measure(characters: int, rate: float, duration: float) -> dict:
    from torchik.live.mvn_source import MvnSource
    from torchik.live.sample import Url
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.pipelines.live import LiveOptions, Publisher, Selection, track_live

    model = load_model("human66")
    links = TRACKED_LINKS["human66"]
    source = MvnSource(Url("udp", "127.0.0.1", 0))
    sender = multiprocessing.get_context("spawn").Process(
        target=_replay, args=(source.address[1], characters, rate, duration + WARM_UP_S))
    sender.start()
    publisher = Publisher(f"torchik-latency-{characters}-{rate:g}", model, rate=rate)
    result = track_live(source, model, lambda names: Selection.build(names, links), publisher=publisher,
                        options=LiveOptions(backlog=1, stop_when_idle_s=1.0, keep_states=False))
    sender.join()
    # the warm-up's share of the published samples left out (by count, not by frames: samples the
    # tracker stepped over were never published, so the frame count would leave out too many)
    latency = result.latency[int(len(result.latency) * WARM_UP_S / (duration + WARM_UP_S)):] * 1e3
    return dict(characters=characters, rate_hz=rate, duration_s=duration, published=int(len(result.latency)),
                samples=result.source_stats["samples"], skipped=sum(result.skipped.values()),
                lost=result.source_stats["lost"],
                latency_ms=dict(p50=float(np.median(latency)), p99=float(np.quantile(latency, 0.99)),
                                max=float(latency.max())) if len(latency) else None,
                step_ms_median=float(np.median(result.step_time) * 1e3) if len(result.step_time) else None,
                step_ms_p99=float(np.quantile(result.step_time, 0.99) * 1e3) if len(result.step_time) else None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds per setting (default 60)")
    parser.add_argument("--only", metavar="N@HZ", action="append",
                        help="run only these settings, e.g. --only 1@240 --only 64@100")
    parser.add_argument("--json", metavar="FILE", help="write the results here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings = SETTINGS if not args.only else [(int(n), float(hz)) for n, hz in (s.split("@") for s in args.only)]
    results = []
    for characters, rate in settings:
        r = measure(characters, rate, args.duration)
        results.append(r)
        lat = r["latency_ms"] or {}
        print(f"{characters:3d} character(s) at {rate:5.0f} Hz: latency p50 {lat.get('p50', float('nan')):6.2f} ms, "
              f"p99 {lat.get('p99', float('nan')):6.2f} ms, max {lat.get('max', float('nan')):7.2f} ms; "
              f"skipped {r['skipped']} of {r['samples']} samples; step median {r['step_ms_median']:.2f} ms, "
              f"p99 {r['step_ms_p99']:.2f} ms", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(dict(machine=platform.processor() or platform.machine(), cpus=torch.get_num_threads(),
                           time=time.strftime("%Y-%m-%dT%H:%M:%S"), results=results), f, indent=2)


if __name__ == "__main__":
    main()
