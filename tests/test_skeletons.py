"""synthetic.skeletons and io.bvh_writer: a scenario written as a HumanIK-named BVH reads back, through
the map `--map auto` picks, as the scenario's own link orientations; and `torchik track` tracks it
without being told the map."""

from __future__ import annotations

import numpy as np
import pytest

from torchik.cli import main
from torchik.io import read
from torchik.io.maps import map_recording
from torchik.method.models import TRACKED_LINKS, load_model
from torchik.synthetic.scenarios import scenario
from torchik.synthetic.skeletons import write_scenario_bvh

LINKS = TRACKED_LINKS["human66"]


@pytest.fixture(scope="module")
def walk():
    model = load_model("human66")
    return model, scenario("walking", model, LINKS, duration=2.0, rate=50.0)


@pytest.mark.parametrize("prefix,toes", [("", True), ("mixamorig:", False)])
def test_a_humanik_bvh_of_a_scenario_maps_back_to_its_orientations(tmp_path, walk, prefix, toes):
    model, recording = walk
    path = write_scenario_bvh(tmp_path / "walk.bvh", recording, model, prefix, toes)
    bvh = read(path)
    assert bvh.links[0] == f"{prefix}Hips" and bvh.meta["units"] == "cm"
    mapped, link_map = map_recording(bvh, "auto", model)
    assert link_map.name == "humanik to human"
    assert ("RightToe" in mapped.links) == toes
    assert mapped.meta["link_map"]["left_out"] == ([] if toes else ["RightToe", "LeftToe"])
    rows = [LINKS.index(link) for link in mapped.links]
    # calibrated on the rest pose, whose up (hips to head) leans 0.02 degrees forward in the model
    assert np.abs(mapped.orientation - recording.orientation[:, rows]).max() < 1e-3
    assert np.abs(mapped.base_position - recording.base_position).max() < 1e-6  # written to 1e-6 cm


def test_track_picks_the_humanik_map_when_the_segments_are_not_the_models_links(tmp_path, walk, monkeypatch, capsys):
    model, recording = walk
    path = write_scenario_bvh(tmp_path / "walk.bvh", recording, model, "mixamorig:")
    monkeypatch.setattr("torchik.pipelines.memory.keep_freed_memory", lambda: True)
    assert main(["track", "--input", str(path), "--model", "human66", "--quiet", "--report",
                 str(tmp_path / "r.json")]) == 0
    assert '"source": "' in (tmp_path / "r.json").read_text() and "humanik to human" in (tmp_path / "r.json").read_text()
