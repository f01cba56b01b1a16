"""The command line (python -m sabre): help text with units and defaults, option checking, a run."""

from __future__ import annotations

import pytest

from sabre.cli import main


@pytest.mark.parametrize("command", ["demo", "episode", "scripted"])
def test_every_option_of_every_command_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "--object" in text and "(default: shelf)" in text
    if command != "scripted":
        for option, default in (("--duration S", "seconds"), ("--replan-rate HZ", "Hz"), ("--threads N", "threads")):
            assert option in text and default in text
        assert "(default: 60.0)" in text if command == "demo" else "(default: 30.0)" in text


@pytest.mark.parametrize("args", [["--duration", "-1"], ["--replan-rate", "0"], ["--threads", "0"], ["--seed", "-3"],
                                  ["--variant", "X"]])
def test_bad_options_are_rejected_with_a_usage_error(args, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["episode", *args])
    assert exit_.value.code == 2
    assert "error" in capsys.readouterr().err


def test_a_short_episode_that_does_not_open_exits_with_one(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    plot = tmp_path / "episode.png"
    code = main(["episode", "--duration", "0.1", "--threads", "1", "--replan-rate", "50", "--plot", str(plot)])
    assert code == 1
    assert plot.exists()
    assert "success: False" in capsys.readouterr().out
