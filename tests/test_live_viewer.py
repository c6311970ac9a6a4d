"""The live viewer (torchik/pipelines/live/viewer.py): a session saved with `--rrd` holds the
entities of `track --rrd` for every character and the live counters, whose last values are the
session's own; the logging is rate-limited and never holds the tracking up; bad viewer URLs are
refused in one line."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import torch

from torchik.live.mvn_source import MvnSource
from torchik.live.sample import Url
from torchik.method.models import TRACKED_LINKS, human_urdf, load_model
from torchik.pipelines.live import LiveOptions, Selection, track_live
from torchik.pipelines.live.viewer import COUNTERS, LiveViewer, ViewerSpec
from torchik.pipelines.replay import Faults, replay
from torchik.pipelines.visuals import visuals
from torchik.synthetic.scenarios import scenario

rerun = pytest.importorskip("rerun")
pytest.importorskip("rerun.chunk")
LINKS = TRACKED_LINKS["human66"]


def test_a_saved_session_holds_every_character_and_the_final_counters(tmp_path):
    torch.set_num_threads(1)
    model = load_model("human66")
    walk = scenario("walking", model, LINKS, duration=1.0, rate=100.0)
    path = tmp_path / "live.rrd"
    viewer = LiveViewer(ViewerSpec(model, LINKS, visuals(human_urdf(66)), path=str(path)), rate=20.0)
    source = MvnSource(Url("udp", "127.0.0.1", 0))
    sender = threading.Thread(target=replay, args=(walk, Url("udp", "127.0.0.1", source.address[1]), 2.0, 2,
                                                   Faults(duplicate=0.05, seed=2)), kwargs=dict(lead_in_s=0.1))
    sender.start()
    start = time.perf_counter()
    result = track_live(source, model, lambda names: Selection.build(names, LINKS), viewer=viewer,
                        options=LiveOptions(backlog=100000, stop_when_idle_s=0.4))
    session = time.perf_counter() - start
    sender.join()
    # at most one snapshot per display period (0.05 s), not one per step; none waited for
    offered = viewer.sent + viewer.left_out
    assert 1 <= offered <= session / 0.05 + 1 and offered < len(result.step_time) / 2
    paths = set(rerun.chunk.RrdReader(path).store().schema().entity_paths())
    for c in (0, 1):
        assert {f"/subject/{c}/estimate/Pelvis", f"/subject/{c}/skeleton", f"/subject/{c}/target/Pelvis",
                f"/subject/{c}/errors/mnte", f"/subject/{c}/joints/jL5S1_rotx"} <= paths
    assert {f"/live/{name}" for name in COUNTERS} <= paths
    assert _last(path, "/live/samples") == result.source_stats["samples"] == 2 * len(walk.time)
    assert _last(path, "/live/duplicates") == result.source_stats["duplicates"] > 0


def _last(path, entity: str) -> float:
    """The last value logged at a scalar entity (rerun's dataframe API, as tests/test_rrd.py reads)."""
    store = rerun.chunk.RrdReader(path).store().stream().collect()
    frame = store.reader(index="time", contents=entity).to_pandas()
    values = [v for v in frame[f"{entity}:Scalars:scalars"] if v is not None and len(v)]
    return float(np.ravel(values[-1])[0])


@pytest.mark.parametrize("url", ["http://127.0.0.1:9876", "rerun+http://127.0.0.1:9876"])
def test_a_bad_viewer_url_is_refused_in_one_line(cli, url):
    code, _, err = cli("live", "--from", "udp://127.0.0.1:0", "--viewer", url, "--quiet")
    assert code == 2 and "rerun+http://" in err and len(err.strip().splitlines()) == 1
