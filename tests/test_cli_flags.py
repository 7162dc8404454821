"""Library errors name the library's parameters; the command line names its flags (stableins.commands.flags)."""

import pytest

from stableins.cli import main
from stableins.commands.flags import FLAGS, as_flag
from stableins.drivers.tcp import parse_address
from stableins.errors import InputError
from stableins.history_store import HistoryStore


def test_the_library_names_the_parameter_and_the_cli_the_flag(tmp_path, capsys):
    blocker = tmp_path / "not-a-directory"
    blocker.write_text("x")
    with pytest.raises(InputError) as caught:
        HistoryStore(blocker).entries("U1")
    assert caught.value.field == "root" and "--store" not in str(caught.value)
    assert main(["history", "U1", "--store", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert "--store" in err and "root" not in err.replace(str(tmp_path), "")


def test_as_flag_rewrites_the_message_and_leaves_other_fields_alone():
    with pytest.raises(InputError) as caught:
        parse_address("tcp://host:abc")
    assert caught.value.field == "driver_spec"
    translated = as_flag(caught.value)
    assert translated.field == "--driver" and "--driver" in str(translated) and "driver_spec" not in str(translated)
    other = as_flag(InputError("bad", path="x.csv", field="f_z"))
    assert other.field == "f_z" and "f_z" in str(other)
    assert len(set(FLAGS.values())) == len(FLAGS)
