"""Progress bars on stderr: shown on a terminal, hidden under -q or when not a TTY."""

from __future__ import annotations

import io
import sys

import pytest

from l3cli.cli.main import cli
from l3cli.progress import progress
from tests.builders import sim_dir


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


class _Pipe(io.StringIO):
    def isatty(self) -> bool:
        return False


@pytest.mark.parametrize("stream,enabled,shown", [
    (_Terminal, None, True), (_Terminal, True, True), (_Terminal, False, False),
    (_Pipe, None, False),
])
def test_progress_follows_the_terminal_and_enabled(monkeypatch, stream, enabled, shown):
    err = stream()
    monkeypatch.setattr(sys, "stderr", err)
    items = list(range(7))
    assert list(progress(items, label="images", enabled=enabled)) == items
    text = err.getvalue()
    assert ("images" in text) == shown and (text == "") == (not shown), repr(text)


def _train_on(monkeypatch, err, tmp_path, *global_opts):
    sim = sim_dir(tmp_path, n=2, shape=(40, 48), seed=31)
    monkeypatch.setattr(sys, "stderr", err)
    out = tmp_path / "t.npz"
    cli.main([*global_opts, "train", str(sim), "-o", str(out), "--levels", "3",
              "--min-samples", "2"], standalone_mode=False)
    assert out.exists()
    return err.getvalue()


def test_train_shows_a_progress_bar_over_images_on_a_terminal(monkeypatch, tmp_path):
    text = _train_on(monkeypatch, _Terminal(), tmp_path)
    assert "statistics" in text and "100%" in text, repr(text)


def test_train_is_quiet_under_q_even_on_a_terminal(monkeypatch, tmp_path):
    assert _train_on(monkeypatch, _Terminal(), tmp_path, "-q") == ""


def test_train_shows_no_progress_when_stderr_is_not_a_terminal(monkeypatch, tmp_path):
    text = _train_on(monkeypatch, _Pipe(), tmp_path)
    assert "statistics" not in text and "%" not in text, repr(text)
    # only the one-line summary, which logs and CI see too (issue 31)
    lines = text.strip().splitlines()
    assert len(lines) == 1 and "classes trained from 2 captures" in lines[0], repr(text)
