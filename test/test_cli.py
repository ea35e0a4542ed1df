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


JSON_TOOLS = [["eval", "kt3dmoseg"], ["eval", "kt3dmoseg-masks"], ["eval", "davis", "DIR"], ["eval", "map", "BAG"],
              ["synth-eval"], ["bench", "pipeline"], ["bench", "soak", "BAG"], ["bench", "fleet"]]


@pytest.mark.parametrize("argv", JSON_TOOLS, ids=" ".join)
def test_a_json_report_without_its_folder_is_refused_before_the_run(argv, tmp_path, capsys, monkeypatch):
    """The report is written when the run ends (minutes later for a map or a soak): its folder is checked first."""
    words = [word for word in argv if word.islower()]
    module = {" ".join(tool): name for tool, name in _tools()}[" ".join(words)]
    monkeypatch.setattr(importlib.import_module(module), "run", lambda args: pytest.fail("the run started"))
    missing = tmp_path / "no_such_folder" / "report.json"
    assert main([*words, *(str(tmp_path) for word in argv if not word.islower()), "--json", str(missing)]) == 2
    err = capsys.readouterr().err
    assert f"moseg {' '.join(words)}: error: --json {missing}: its folder does not exist" in err
