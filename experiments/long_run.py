"""Peak memory and time of `torchik track` on long runs: a recording file read a chunk at a time
(issue 16), or with --scenario the built-in walking scenario made as it is tracked (issue 36); an
hour at 100 Hz must fit a laptop: under 1 GB.

Each run is the command line in a child process writing its report and trajectory (and an .rrd
with --rrd). The child's peak resident memory (the kernel's ru_maxrss, from wait4) and wall time
are printed and written to --json, with its resident memory sampled every --every seconds (from
/proc) to show whether it levels off. The script exits 1 when a run's peak is 1 GB (1000 MB) or more.

    nice python experiments/long_run.py --minutes 10 60 --workdir /tmp/long_run --json long_run.json
    nice python experiments/long_run.py --scenario --minutes 60 --workdir /tmp/long_run

Without --scenario, a Human66 walking recording of each duration at --rate is written once (kept in
--workdir, so a rerun measures only the tracking) and tracked with --input. Input size for scale:
an hour of Human66's 23 tracked links at 100 Hz is 0.8 GB of float64 orientations and angular
velocities in the recording itself. With --scenario, `torchik track --scenario walking --duration`
makes the same samples a chunk at a time as it tracks them.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

LIMIT_MB = 1000.0  # 1 GB


def recording(workdir: Path, minutes: float, rate: float) -> Path:
    """The cached walking recording of `minutes` at `rate` Hz (generated on first use, in a child)."""
    path = workdir / f"walking_{minutes:g}min_{rate:g}hz.npz"
    if not path.exists():
        # generated in a spawned child: the tracking child's ru_maxrss starts from this process's
        # peak (its fork is counted until exec), so an hour's recording made here would be counted
        # as the tracker's memory
        child = multiprocessing.get_context("spawn").Process(target=_generate, args=(path, minutes, rate))
        child.start()
        child.join()
        if child.exitcode != 0:
            raise SystemExit(f"long_run: generating {path} failed (exit {child.exitcode})")
    return path


def _generate(path: Path, minutes: float, rate: float) -> None:
    from torchik.io import save_recording
    from torchik.method.models import TRACKED_LINKS, load_model
    from torchik.synthetic.scenarios import scenario

    start = time.perf_counter()
    rec = scenario("walking", load_model("human66"), TRACKED_LINKS["human66"], duration=60.0 * minutes, rate=rate)
    part = path.with_name(path.name + ".part")
    save_recording(rec, part)
    part.rename(path)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - start:.0f} s", flush=True)


def measure(source: list[str], stem: Path, rrd: bool, every: float) -> dict:
    """Track `source` (--input FILE or --scenario ...) with the command line in a child; its peak
    RSS (MB), its RSS sampled every `every` s, wall time (s) and report."""
    command = [sys.executable, "-m", "torchik", "track", *source, "--model", "human66", "--quiet",
               "--force", "--report", f"{stem}.json", "--out", f"{stem}_trajectory.npz"]
    if rrd:
        command += ["--rrd", f"{stem}.rrd"]
    print("$", " ".join(command), flush=True)
    start = time.perf_counter()
    child = subprocess.Popen(command)
    samples = []  # (s since the start, RSS MB)
    while True:
        pid, status, usage = os.wait4(child.pid, os.WNOHANG)
        if pid:
            break
        rss = _rss_mb(child.pid)
        if rss is not None:
            samples.append((round(time.perf_counter() - start, 1), round(rss, 1)))
        time.sleep(every)
    wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"long_run: `{' '.join(command)}` exited {child.returncode}")
    report = json.loads(Path(f"{stem}.json").read_text())
    # the child's peak is at least this process's at the fork: printed beside it so a reader sees it is not that
    parent_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return dict(command=" ".join(command), peak_rss_mb=usage.ru_maxrss / 1024,  # ru_maxrss: KiB on Linux
                measuring_process_rss_mb=parent_mb, wall_s=wall, frames=report["frames"],
                step_time_ms_median=report["step_time_ms"]["median"], mnte_p99=report["mnte"]["p99"],
                rss_samples_mb=samples)


def _rss_mb(pid: int) -> float | None:
    """The resident memory of process `pid` now (MB, as ru_maxrss counts: KiB / 1024), None once it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def _levels(samples: list, parts: int = 4) -> str:
    """The RSS at the end of each quarter of the run, to see whether it levels off."""
    if not samples:
        return "no samples"
    end = samples[-1][0]
    picks = [max((s for s in samples if s[0] <= end * k / parts), default=samples[0]) for k in range(1, parts + 1)]
    return ", ".join(f"{rss:.0f} MB at {t:.0f} s" for t, rss in picks)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, nargs="+", default=[10.0, 60.0], help="durations (default 10 60)")
    parser.add_argument("--rate", type=float, default=100.0, help="frames per second (default 100)")
    parser.add_argument("--scenario", action="store_true",
                        help="track `--scenario walking`, made as it is tracked, instead of a recording file")
    parser.add_argument("--workdir", type=Path, default=Path("long_run"), help="recordings and outputs (default ./long_run)")
    parser.add_argument("--rrd", action="store_true", help="write a rerun .rrd as well (needs the viz extra)")
    parser.add_argument("--every", type=float, default=2.0, help="seconds between RSS samples (default 2)")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    if not all(0 < m < float("inf") for m in args.minutes) or not 0 < args.rate < float("inf"):
        parser.error("--minutes and --rate must be positive and finite")
    args.workdir.mkdir(parents=True, exist_ok=True)
    results = {}
    for minutes in args.minutes:
        if args.scenario:
            source = ["--scenario", "walking", "--duration", f"{60 * minutes:g}", "--rate", f"{args.rate:g}"]
            stem = args.workdir / f"scenario_walking_{minutes:g}min_{args.rate:g}hz"
        else:
            path = recording(args.workdir, minutes, args.rate)
            source, stem = ["--input", str(path)], args.workdir / path.stem
        result = measure(source, stem, args.rrd, args.every)
        results[f"{minutes:g} min"] = result
        print(f"{minutes:g} min at {args.rate:g} Hz ({result['frames']} frames, "
              f"{'scenario' if args.scenario else 'file'}): peak RSS {result['peak_rss_mb']:.0f} MB "
              f"(this process: {result['measuring_process_rss_mb']:.0f} MB), {result['wall_s']:.0f} s "
              f"(step median {result['step_time_ms_median']:.2f} ms); RSS {_levels(result['rss_samples_mb'])}",
              flush=True)
    if args.json:
        args.json.write_text(json.dumps(dict(rate_hz=args.rate, limit_mb=LIMIT_MB, results=results), indent=2) + "\n")
    over = [key for key, result in results.items() if result["peak_rss_mb"] >= LIMIT_MB]
    if over:
        print(f"long_run: peak RSS of {LIMIT_MB:g} MB or more: {', '.join(over)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
