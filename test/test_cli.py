"""The `moseg` command line: every registered tool loads and describes its options."""

from __future__ import annotations

import importlib

import pytest

from moseg_ros.cli import COMMANDS, GROUPS, main


def _tools():
    for name, (module, _) in COMMANDS.items():
        yield [name], module
    for group, (_, tools) in GROUPS.items():
        for name, (module, _) in tools.items():
            yield [group, name], module


@pytest.mark.parametrize("words,module", list(_tools()), ids=lambda v: " ".join(v) if isinstance(v, list) else v)
def test_every_tool_has_help_and_a_runner(words, module, capsys):
    loaded = importlib.import_module(module)
    assert callable(loaded.add_arguments) and callable(loaded.run)
    with pytest.raises(SystemExit) as exit_info:
        main(words + ["--help"])
    assert exit_info.value.code == 0
    assert "usage: moseg " + " ".join(words) in capsys.readouterr().out


def test_unknown_command_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["frobnicate"])
    assert exit_info.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
