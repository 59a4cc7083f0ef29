import pathlib
import sys

import pytest

# toys.py and helpers.py are imported by module name (also as `--factory toys:make_toy`).
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))


@pytest.fixture(scope="session", autouse=True)
def _stop_shared_servers():
    yield
    import helpers

    helpers.stop_shared_servers()
