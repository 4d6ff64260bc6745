"""The Mitsuba variant: libLLVM found by version, the order of choice, the fall-back to scalar."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from icefarm.errors import InputError
from icefarm.scene.variants import choose_variant, find_libllvm, llvm_version

ROOT = Path(__file__).resolve().parents[1]


def test_llvm_version_from_names():
    assert llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert llvm_version("/usr/lib/x86_64-linux-gnu/libLLVM-14.0.6.so.1") == 14
    assert llvm_version("/usr/lib/llvm-18/lib/libLLVM.so") == 18
    assert llvm_version("/usr/lib/libLLVM.so") is None
    assert llvm_version("/usr/lib/libLLVMSupport.a") is None


def test_find_libllvm_refuses_old_versions(tmp_path):
    for name in ("libLLVM-14.so.1", "libLLVM-15.so.1", "libLLVM-16.so.1", "libLLVM.so"):
        (tmp_path / name).write_bytes(b"")
    assert find_libllvm([tmp_path]) is None
    (tmp_path / "libLLVM-17.so").write_bytes(b"")
    (tmp_path / "libLLVM.so.19.1").write_bytes(b"")
    assert find_libllvm([tmp_path]) == tmp_path / "libLLVM.so.19.1"
    assert find_libllvm([tmp_path / "missing"]) is None


def test_choose_variant_order_and_refusals():
    assert choose_variant("auto", cuda=False, llvm=False) == "scalar_rgb"
    assert choose_variant("auto", cuda=False, llvm=True) == "llvm_ad_rgb"
    assert choose_variant("auto", cuda=True, llvm=True) == "cuda_ad_rgb"
    assert choose_variant("scalar_rgb", cuda=True, llvm=True) == "scalar_rgb"
    with pytest.raises(InputError, match="llvm_ad_rgb"):
        choose_variant("llvm_ad_rgb", cuda=False, llvm=False)
    with pytest.raises(InputError, match="CUDA"):
        choose_variant("cuda_ad_rgb", cuda=False, llvm=True)


@pytest.mark.slow
@pytest.mark.parametrize("fake", [None, "libLLVM.so.19.1"])
def test_pick_variant_falls_back_to_scalar_without_good_llvm(tmp_path, fake):
    """A fresh process (Dr.Jit reads the path at import): no libLLVM, or a fake one, gives scalar."""
    if fake:
        (tmp_path / fake).write_bytes(b"not a library")
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env.update(CUDA_VISIBLE_DEVICES="", DRJIT_LIBCUDA_PATH=str(tmp_path / "no-libcuda.so"),
               PYTHONPATH=str(ROOT))
    code = ("import os; from icefarm.scene.variants import pick_variant; "
            f"print(pick_variant('auto', search_dirs=[{str(tmp_path)!r}])); "
            "print(os.environ['DRJIT_LIBLLVM_PATH'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    variant, path = out.stdout.split()
    assert variant == "scalar_rgb"
    assert (path == str(tmp_path / fake)) if fake else "nonexistent" in path
