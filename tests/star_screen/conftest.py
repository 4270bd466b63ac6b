import pytest

from sim.time import Epoch
from star_screen.catalog import Catalog

from .star_screen_helpers import EPOCH_ISO


@pytest.fixture(scope="session")
def epoch():
    return Epoch.from_iso(EPOCH_ISO)


@pytest.fixture(scope="session")
def catalog():
    return Catalog.load()
