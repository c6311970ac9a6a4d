"""bench: every pipeline of the benchmark runs and tracks, the table's ratios and its one-subject
line compare the same measured quantity, and bad input is refused; --dynamics times inverse dynamics
against pinocchio's rnea after checking they agree, eager and compiled."""

import re

import pytest

import torchik.method.captured as captured
from torchik.cli import main
from torchik.pipelines.bench import Measurement, _percentiles, run, table


def test_every_pipeline_runs_and_tracks_the_motion(monkeypatch):
    pytest.importorskip("pinocchio")
    # the compiled loop's step uncompiled: its plumbing without TorchInductor's cost (test_captured compiles)
    monkeypatch.setattr(captured, "capture", lambda fn, inputs: fn)
    results = run(models=("human48",), batches=(3,), loop_steps=20, min_seconds=0.5, max_steps=5, progress=False)
    pipelines = {r.pipeline for r in results}
    assert {"torchik batched", "torchik+piqp", "torchik compiled", "pinocchio+piqp"} <= pipelines
    for r in results:
        assert r.subject_steps_per_second > 0 and r.steps > 0
        # each pipeline follows the walking-like motion from its exact start (MNTE 1e-4: 0.8 degrees)
        assert r.final_mnte < 1e-4, (r.pipeline, r.final_mnte)
    batched = next(r for r in results if r.pipeline == "torchik batched")
    assert batched.batch == 3 and batched.unsolved_fraction == 0.0
    loops = [r for r in results if r.batch == 1]
    assert all(0 < r.median_step_ms <= r.p99_step_ms for r in loops)
    compiled = next(r for r in results if r.pipeline == "torchik compiled")
    assert compiled.compile_seconds is not None and compiled.compile_seconds >= 0
    printed = table(results)
    assert "human48" in printed
    if "pinocchio+daqp" in pipelines:  # the one-subject comparison, median to median
        assert "human48, one subject: torchik compiled" in printed


def test_bad_batch_size_is_refused_with_exit_code_2(capsys):
    assert main(["bench", "--batch", "0", "--quiet"]) == 2
    assert "batch sizes must be positive" in capsys.readouterr().err


def test_with_compile_each_batch_size_has_a_captured_row_after_its_eager_one(monkeypatch):
    """--compile: the captured step (uncompiled here) beside the eager one, both tracking the motion,
    a replayed step counted as one iteration."""
    monkeypatch.setattr(captured, "capture", lambda fn, inputs: fn)
    results = run(models=("human48",), batches=(3, 40), loops=False, min_seconds=0.5, max_steps=8, progress=False,
                  compiled=True)
    assert [(r.pipeline, r.batch) for r in results] == [
        ("torchik batched", 3), ("torchik batched compiled", 3), ("torchik batched", 40), ("torchik batched compiled", 40)]
    for r in results:
        assert r.final_mnte < 1e-4 and r.unsolved_fraction == 0.0, (r.pipeline, r.batch)
    for r in results[1::2]:
        assert r.compile_seconds is not None and r.iterations_mean == 1.0  # every timed step replayed, no bound active
    assert "batched compiled, the capture's time" in table(results)


def test_with_compile_a_step_that_cannot_be_captured_stops_the_bench_with_exit_code_2(monkeypatch, capsys):
    """No row named compiled may hold an eager step's figures: where the capture fails, the bench
    stops and says so."""
    from torchik.method.capture import CaptureError

    def fails(fn, inputs):
        raise CaptureError("could not compile the step (no compiler, for this test)")

    monkeypatch.setattr(captured, "capture", fails)
    with pytest.warns(UserWarning, match="runs eagerly"):
        code = main(["bench", "--models", "human48", "--batch", "3", "--no-loops", "--compile", "--max-steps", "3",
                     "--seconds", "0.2", "--quiet"])
    assert code == 2
    assert "--compile: the step could not be captured here" in capsys.readouterr().err


def _measured(model: str, pipeline: str, batch: int, step_ms: list[float]) -> Measurement:
    """A measurement as the bench makes it from its steps' times (ms), each timed alone."""
    times = [t / 1e3 for t in step_ms]
    return Measurement(model, pipeline, batch, len(times), sum(times), batch * len(times) / sum(times),
                       **_percentiles(times))


def test_the_tables_ratio_and_the_one_subject_line_compare_the_same_median_step():
    """Issue 36: one run printed `torchik compiled B=1 ... 0.7x vs best peer, 0.44 ms/step, p50 0.134 ms`
    and below it `torchik compiled 0.134 ms median step, pinocchio+daqp 0.280 ms: 2.08x`: the row's ratio
    was the mean's, the line's the median's. Here a step of 0.134 ms, one in ten 3.2 ms (mean 0.44 ms):
    the row's ratio, the line's and the batched row's are all at the median step."""
    results = [_measured("human66", "torchik batched", 64, [2.0] * 20 + [9.0] * 5),
               _measured("human66", "torchik compiled", 1, [0.134] * 90 + [3.2] * 10),
               _measured("human66", "pinocchio+daqp", 1, [0.280] * 100),
               _measured("human66", "pinocchio+piqp", 1, [0.9] * 100)]
    lines = table(results).splitlines()
    row = lambda pipeline: next(line for line in lines if line.startswith("human66 ") and pipeline in line)  # noqa: E731
    line = next(line for line in lines if line.startswith("human66, one subject"))
    ratios = lambda text: re.findall(r"(\d+\.\d+)x", text)  # noqa: E731
    assert ratios(row("torchik compiled")) == ratios(line) == [f"{0.280 / 0.134:.2f}"]
    assert ratios(row("torchik batched")) == [f"{64 * 0.280 / 2.0:.2f}"]  # per subject: B over the median step
    # the table says which: the ratio's column is at the median, its legend says so
    assert "vs best peer p50" in lines[0] and any(text.startswith("p50, p99, mean: a step's median") for text in lines)


def test_the_dynamics_bench_agrees_with_pinocchio_then_times_both(monkeypatch, tmp_path, capsys):
    """`torchik bench --dynamics`: a row per model, device and batch, torchik checked against pinocchio
    first; with --compile the compiled call too (its capture here the function itself: test_capture
    compiles), its capture's time said apart."""
    import json

    pytest.importorskip("pinocchio")
    from torchik.method.dynamics import compiled
    from torchik.pipelines import bench_dynamics

    monkeypatch.setattr(compiled, "capture", lambda fn, inputs: fn)
    results = bench_dynamics.run(models=("human48",), batches=(8, 40), compiled=True, progress=False)
    assert [(r.model, r.device, r.batch) for r in results] == [("human48", "cpu", 8), ("human48", "cpu", 40)]
    for r in results:
        assert r.difference <= 1e-9 and r.torchik_ms > 0 and r.pinocchio_loop_ms > 0 and r.compiled_ms > 0
        assert r.speedup == pytest.approx(r.pinocchio_loop_ms / r.torchik_ms)
    printed = bench_dynamics.table(results)
    assert "loop/torchik" in printed and "loop/compiled" in printed and "capture's time" in printed
    out = tmp_path / "dynamics.json"
    assert main(["bench", "--dynamics", "--models", "human48", "--batch", "8", "--device", "cpu", "--quiet",
                 "--json", str(out)]) == 0
    assert "torchik bench --dynamics" in capsys.readouterr().out
    rows = json.loads(out.read_text())["dynamics"]
    assert [(row["model"], row["batch"]) for row in rows] == [("human48", 8)] and rows[0]["speedup"] > 0
