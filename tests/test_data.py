"""The files torchik reads at run time are package data, found through importlib.resources, and the
repository's models/maps shows the same files (one copy, not two that can drift)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from importlib import resources
from pathlib import Path

import torchik
from torchik.data import version
from torchik.io.maps import built_in_maps, load_map

REPOSITORY = Path(__file__).resolve().parents[1]


def test_every_built_in_map_is_read_through_importlib_resources():
    folder = resources.files("torchik.data") / "maps"
    names = sorted(p.name.removesuffix(".toml") for p in folder.iterdir() if p.name.endswith(".toml"))
    assert names == built_in_maps() and "cmu_to_human" in names
    for name in names:
        spec = tomllib.loads((folder / f"{name}.toml").read_text())
        assert load_map(name).name == spec["name"]


def test_the_repository_models_maps_is_the_package_folder_not_a_copy():
    shown = REPOSITORY / "models" / "maps"
    assert shown.is_symlink() and shown.resolve() == (REPOSITORY / "torchik" / "data" / "maps").resolve()


def test_version_is_pyproject_version_as_installed():
    declared = tomllib.loads((REPOSITORY / "pyproject.toml").read_text())["project"]["version"]
    assert torchik.__version__ == version() == declared
    out = subprocess.run([sys.executable, "-m", "torchik", "--version"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == f"torchik {declared}"
