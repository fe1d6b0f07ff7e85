"""`baarda view` without a display and the help of `view` and `review` (issue 23, item 11)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from baarda.pipeline import cli


def _help(capsys, command):
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    return capsys.readouterr().out


def test_has_display():
    assert not cli.has_display({}) or cli.sys.platform in ("darwin", "win32", "cygwin")
    assert cli.has_display({"DISPLAY": ":0"})
    assert cli.has_display({"WAYLAND_DISPLAY": "wayland-0"})
    assert not cli.has_display({"DISPLAY": ""}) or cli.sys.platform in ("darwin", "win32", "cygwin")


def test_view_without_display_says_what_to_do(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "bundle.rrd").write_bytes(b"")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_SOCKET", raising=False)
    monkeypatch.setattr(cli.sys, "platform", "linux")
    called = []
    monkeypatch.setattr(cli.subprocess, "call", lambda cmd: called.append(cmd) or 0)
    assert cli.main(["view", str(run)]) == cli.VIEW_NO_DISPLAY
    err = capsys.readouterr().err
    assert not called                                     # the viewer is not started to fail with winit
    assert "no display" in err and "DISPLAY" in err and "baarda review" in err and "--print" in err
    assert "winit" not in err
    # --print still works without a display
    assert cli.main(["view", str(run), "--print"]) == 0
    assert "bundle.rrd" in capsys.readouterr().out
    # with a display the viewer is started
    monkeypatch.setenv("DISPLAY", ":0")
    assert cli.main(["view", str(run)]) == 0 and called


def test_review_and_view_help_list_their_own_exit_codes(capsys):
    review = _help(capsys, "review")
    codes = re.findall(r"^  (\d+) ", review.split("exit status:")[1], re.M)
    assert codes == ["0", "2", "3", "130"]
    assert "adjustment" not in review.split("exit status:")[1]          # run's code 1 is not review's
    view = _help(capsys, "view")
    codes = re.findall(r"^  (\d+) ", view.split("exit status:")[1], re.M)
    assert codes == ["0", "2", str(cli.VIEW_NO_DISPLAY)]
    assert "display" in view.split("exit status:")[1]
