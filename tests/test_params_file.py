""".parm files: reading, refusing and writing (the shipped params/defaults.parm is generated and
checked in tests/test_paramdoc.py)."""
from companion.params import read_parm_file


def test_a_name_set_twice_is_refused_with_file_and_line(tmp_path):
    import pytest

    from companion.params import ParamError

    path = tmp_path / "twice.parm"
    path.write_text("NAV_SPEED_KMH 40\nMPC_HORIZON 3\nNAV_SPEED_KMH 45\n")
    with pytest.raises(ParamError, match=r"twice\.parm:3: NAV_SPEED_KMH is set twice"):
        read_parm_file(path)


def test_write_validates_and_keeps_permissions(tmp_path):
    import os

    import pytest

    from companion.params import ParamError, write_parm_file

    path = tmp_path / "p.parm"
    write_parm_file(path, {"MPC_HORIZON": 3})
    os.chmod(path, 0o640)
    write_parm_file(path, {"MPC_HORIZON": 4})
    assert path.stat().st_mode & 0o777 == 0o640 and read_parm_file(path) == {"MPC_HORIZON": 4}
    with pytest.raises(ParamError, match="MPC_HORIZON"):
        write_parm_file(path, {"MPC_HORIZON": 99})
    assert read_parm_file(path) == {"MPC_HORIZON": 4}   # nothing written
