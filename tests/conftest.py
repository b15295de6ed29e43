"""Shared test configuration: hypothesis profiles and the optional external data folder."""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# ci: deterministic (derandomised) so a CI run is reproducible; dev: random exploration.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("stress", max_examples=2000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))

REPO = Path(__file__).resolve().parents[1]
SHARED_FAP = REPO.parent / "shared" / "data" / "fap"


def real_fap_files() -> list[Path]:
    return sorted(SHARED_FAP.rglob("*.fap")) if SHARED_FAP.is_dir() else []


@pytest.fixture
def real_files() -> list[Path]:
    files = real_fap_files()
    if not files:
        pytest.skip("../shared/data/fap is not present (external suite)")
    return files
