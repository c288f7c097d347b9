"""The shipped params/defaults.parm is the registry at its defaults (regenerate with
``python -m companion.params > params/defaults.parm``)."""
from pathlib import Path

from companion.params import default_values, read_parm_file, registry_parm_text

SHIPPED = Path(__file__).resolve().parents[1] / "params" / "defaults.parm"


def test_shipped_defaults_file_matches_registry():
    assert read_parm_file(SHIPPED) == default_values()
    assert SHIPPED.read_text() == registry_parm_text()
