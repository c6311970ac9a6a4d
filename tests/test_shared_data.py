"""Every recording file converts to a valid recording that the .npz format reads back the same: the
files the tests write as the real ones are laid out (a Plug-in Gait static trial and walk, an MVN
export, a HumanIK BVH), and every real recording of ../shared/data (each skipped, by name, when
../shared is not beside the checkout)."""

import numpy as np
import pytest
from conftest import DATA, shared_file

from torchik.io import load_recording, read, save_recording

# the recordings ../shared/data/README.md lists, and any other reader's file there
KNOWN = ("bvh/bandai_run_normal_001.bvh", "bvh/bandai_run_normal_002.bvh", "bvh/bandai_walk_normal_001.bvh",
         "bvh/bandai_walk_normal_002.bvh", "bvh/cmu_131_01.bvh", "c3d/HC002D02.c3d", "c3d/HC002D06.c3d",
         "c3d/HC002D25.c3d", "c3d/HC030A01.c3d", "c3d/HC030A05.c3d", "c3d/HC030A22.c3d", "mvnx/test_mocap.mvnx")
SHARED_FILES = sorted(set(KNOWN) | {p.relative_to(DATA).as_posix() for p in DATA.glob("*/*")
                                    if p.suffix.lower() in (".mvnx", ".bvh", ".c3d")})


def converts_and_reads_back(path, tmp_path):
    rec = read(str(path))
    assert len(rec.time) > 10 and len(rec.links) >= 19
    R = rec.orientation[~np.isnan(rec.orientation).any(axis=(-1, -2))]
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < 1e-6
    back = load_recording(save_recording(rec, tmp_path / "r.npz"))
    assert np.array_equal(back.orientation, rec.orientation, equal_nan=True) and back.links == rec.links
    assert back.meta["skeleton"] == rec.meta["skeleton"]  # what builds a subject's model survives the conversion


@pytest.fixture(scope="module")
def humanik_bvh(tmp_path_factory, mvn_export):
    from torchik.synthetic.skeletons import write_scenario_bvh

    path = tmp_path_factory.mktemp("bvh") / "walk.bvh"
    return write_scenario_bvh(path, mvn_export.walking, mvn_export.model, "mixamorig:")


@pytest.mark.parametrize("written", ["c3d static trial", "c3d walk", "mvnx", "bvh"])
def test_every_written_file_converts_and_reads_back(written, request, tmp_path):
    path = {"c3d static trial": lambda: request.getfixturevalue("pig_session").static,
            "c3d walk": lambda: request.getfixturevalue("pig_session").walk,
            "mvnx": lambda: request.getfixturevalue("mvn_export").path,
            "bvh": lambda: request.getfixturevalue("humanik_bvh")}[written]()
    converts_and_reads_back(path, tmp_path)


@pytest.mark.parametrize("relative", SHARED_FILES)
def test_every_shared_file_converts_and_reads_back(relative, tmp_path):
    converts_and_reads_back(shared_file(relative), tmp_path)
