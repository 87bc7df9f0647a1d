"""Shared test fixtures: paths to the real captures in ../shared (skipped with a reason when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_SAMPLES = REPO.parent / "shared" / "rgbd_samples"
BUNDLED_SAMPLE = REPO / "data_samples" / "tissue"


@pytest.fixture
def shared_samples() -> Path:
    if not SHARED_SAMPLES.is_dir():
        pytest.skip(f"real captures not available: {SHARED_SAMPLES} is absent")
    return SHARED_SAMPLES
