"""Shared fixtures: the repository, the `aorender` command built beside the module, and
whether a GPU adapter is available."""

import os
import pathlib
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def repo():
    return REPO


@pytest.fixture(scope="session")
def cli():
    """The release `aorender` binary (AORENDER_BIN, else target/release/aorender): the
    Python results are compared with its output, so a missing binary is a failure."""
    target = os.environ.get("CARGO_TARGET_DIR", str(REPO / "target"))
    path = pathlib.Path(os.environ.get("AORENDER_BIN", pathlib.Path(target) / "release" / "aorender"))
    assert path.is_file(), f"{path} is missing: build it with cargo build --release"
    return path


@pytest.fixture(scope="session")
def has_gpu(cli):
    """Whether wgpu sees an adapter; outside CI its absence skips the GPU tests loudly,
    in CI it fails them (scripts/run installs lavapipe)."""
    listed = subprocess.run([str(cli), "adapters"], capture_output=True, text=True)
    found = listed.returncode == 0 and listed.stdout.strip() != ""
    if not found and not os.environ.get("CI"):
        pytest.skip(f"no GPU adapter (aorender adapters: {listed.stderr.strip() or 'none listed'})")
    assert found, f"no GPU adapter in CI: {listed.stderr.strip()}"
    return True
