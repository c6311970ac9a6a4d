"""Peak memory and time of `torchik track` on long recordings (issue 16: an hour at 100 Hz must fit a
laptop; target under 1 GB).

For each duration, a Human66 walking recording at --rate is written once (kept in --workdir, so a
rerun measures only the tracking), then tracked by the command line in a child process writing its
report and trajectory (and an .rrd with --rrd). The child's peak resident memory (the kernel's
ru_maxrss, from wait4) and wall time are printed and written to --json.

    nice python experiments/long_run.py --minutes 10 60 --workdir /tmp/long_run --json long_run.json

Input size for scale: an hour of Human66's 23 tracked links at 100 Hz is 0.8 GB of float64
orientations and angular velocities in the recording itself.
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


def measure(source: Path, workdir: Path, rrd: bool) -> dict:
    """Track `source` with the command line in a child; its peak RSS (MB), wall time (s) and report."""
    stem = workdir / source.stem
    command = [sys.executable, "-m", "torchik", "track", "--input", str(source), "--model", "human66", "--quiet",
               "--force", "--report", f"{stem}.json", "--out", f"{stem}_trajectory.npz"]
    if rrd:
        command += ["--rrd", f"{stem}.rrd"]
    start = time.perf_counter()
    child = subprocess.Popen(command)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    child.returncode = os.waitstatus_to_exitcode(status)
    if child.returncode != 0:
        raise SystemExit(f"long_run: `{' '.join(command)}` exited {child.returncode}")
    report = json.loads(Path(f"{stem}.json").read_text())
    # the child's peak is at least this process's at the fork: printed beside it so a reader sees it is not that
    parent_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return dict(peak_rss_mb=usage.ru_maxrss / 1024, measuring_process_rss_mb=parent_mb,  # ru_maxrss: KiB on Linux
                wall_s=wall, frames=report["frames"],
                step_time_ms_median=report["step_time_ms"]["median"], mnte_p99=report["mnte"]["p99"],
                recording_mb=source.stat().st_size / 1e6)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, nargs="+", default=[10.0, 60.0], help="durations (default 10 60)")
    parser.add_argument("--rate", type=float, default=100.0, help="frames per second (default 100)")
    parser.add_argument("--workdir", type=Path, default=Path("long_run"), help="recordings and outputs (default ./long_run)")
    parser.add_argument("--rrd", action="store_true", help="write a rerun .rrd as well (needs the viz extra)")
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    if not all(0 < m < float("inf") for m in args.minutes) or not 0 < args.rate < float("inf"):
        parser.error("--minutes and --rate must be positive and finite")
    args.workdir.mkdir(parents=True, exist_ok=True)
    results = {}
    for minutes in args.minutes:
        result = measure(recording(args.workdir, minutes, args.rate), args.workdir, args.rrd)
        results[f"{minutes:g} min"] = result
        print(f"{minutes:g} min at {args.rate:g} Hz ({result['frames']} frames, recording {result['recording_mb']:.0f} MB): "
              f"peak RSS {result['peak_rss_mb']:.0f} MB (this process: {result['measuring_process_rss_mb']:.0f} MB), "
              f"{result['wall_s']:.0f} s "
              f"(step median {result['step_time_ms_median']:.2f} ms)", flush=True)
    if args.json:
        args.json.write_text(json.dumps(dict(rate_hz=args.rate, results=results), indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
