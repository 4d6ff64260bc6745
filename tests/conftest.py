from pathlib import Path

import numpy as np
import pytest
import trimesh

SHARED_MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


@pytest.fixture
def shared_mesh():
    """Path of a mesh in ../shared/meshes; skips when the folder is not beside the repo."""

    def get(name: str) -> Path:
        path = SHARED_MESHES / name
        if not path.is_file():
            pytest.skip(f"{path} not available")
        return path

    return get


@pytest.fixture
def sphere() -> trimesh.Trimesh:
    """A 0.3 m icosphere centred on the origin."""
    return trimesh.creation.icosphere(subdivisions=4, radius=0.15)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(7)
