"""Where the tests find the project and its neighbours, wherever a test module sits under tests/."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
"""The project's checkout (README.md, examples/, tools/ beside compass/)."""

TEST_DATA = ROOT / "tests" / "data"
"""Data kept for the tests (reference C sources, headers)."""

SHARED = ROOT.parent / "shared"
"""The team's shared folder beside the checkout (real recordings under data/)."""


def load_tool(name: str):
    """The script ``tools/NAME.py`` imported as a module (tools/ is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
