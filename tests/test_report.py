"""Reports say which machine and which BLAS kernel a figure came from."""

import os
import platform
import subprocess
import sys

import pytest

from napari_edgecme._report import blas_kernel, machine_info, machine_line


def test_machine_line_names_the_blas_kernel_a_run_used():
    info = machine_info()
    line = machine_line(info)
    assert f"numpy {info['numpy']}" in line
    if info["blas_kernel"] is None:
        assert "OpenBLAS kernel" not in line
    else:
        assert f"OpenBLAS kernel {info['blas_kernel']}," in line


def test_blas_kernel_follows_openblas_coretype():
    if blas_kernel() is None:
        pytest.skip("numpy does not bundle OpenBLAS here")
    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("OPENBLAS_CORETYPE names x86 kernels")
    env = {**os.environ, "OPENBLAS_CORETYPE": "Haswell"}  # AVX2: any x86-64 CI machine
    out = subprocess.run([sys.executable, "-c", "from napari_edgecme._report import "
                          "blas_kernel; print(blas_kernel())"], env=env, capture_output=True,
                         text=True, check=True, timeout=120).stdout.split()
    assert out == ["Haswell"]


def test_machine_line_without_a_kernel_reads_as_before():
    info = {**machine_info(), "blas_kernel": None}
    assert "OpenBLAS" not in machine_line(info)
