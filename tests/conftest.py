from pathlib import Path

import pytest

#: ../shared beside the repository (the seed papers and real logs); absent in some checkouts.
SHARED = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture
def shared_dir():
    if not SHARED.is_dir():
        pytest.skip("../shared is not beside the repository")
    return SHARED


@pytest.fixture
def real_data(shared_dir):
    path = shared_dir / "data" / "real"
    if not path.is_dir():
        pytest.skip("../shared/data/real is absent")
    return path
