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


@pytest.fixture(scope="module")
def mi():
    """Mitsuba on a JIT variant (the ice integrator needs one); skips where there is none."""
    from icefarm.scene.variants import pick_variant

    variant = pick_variant("auto")
    if variant == "scalar_rgb":
        pytest.skip("no JIT variant here: the ice integrator needs llvm_ad_rgb or cuda_ad_rgb")
    import mitsuba

    mitsuba.set_variant(variant)
    return mitsuba
