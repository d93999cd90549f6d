from pathlib import Path

import pytest

from nlpcal.batch.ledger import Ledger
from nlpcal.results import Document
from nlpcal.schemas import validate

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


@pytest.fixture(autouse=True)
def documents_follow_their_schemas(monkeypatch):
    """Every document a test makes, and so every document a command writes in the tests, is
    checked against the schema its kind ships (`nlpcal.schemas`)."""
    to_dict, ledger = Document.to_dict, Ledger.document

    def checked(make):
        def wrapper(self):
            document = make(self)
            validate(document)
            return document

        return wrapper

    monkeypatch.setattr(Document, "to_dict", checked(to_dict))
    monkeypatch.setattr(Ledger, "document", checked(ledger))
