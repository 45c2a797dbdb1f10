"""fd 2 captures shared between threads (LibRaw's messages) and the real stderr beside them."""

from __future__ import annotations

import os
import threading

from l3cli.io.fd2 import STDERR_LOCK, captured


def _say(text: str) -> None:
    os.write(2, text.encode())  # as C code does: straight to the file descriptor


def test_overlapping_captures_keep_their_own_tagged_lines():
    a_in, b_done = threading.Event(), threading.Event()
    got: dict[str, list[str]] = {}

    def second():
        a_in.wait()
        with captured("b.dng") as lines:
            _say("b.dng: data corrupted at 7\n")
        got["b"] = lines
        b_done.set()

    t = threading.Thread(target=second)
    t.start()
    with captured("a.dng") as lines:
        a_in.set()
        b_done.wait(10)
        _say("a.dng: Unexpected end of file\nno tag at all\n")
    t.join()
    assert lines == ["a.dng: Unexpected end of file", "no tag at all"]
    assert got["b"] == ["b.dng: data corrupted at 7"]


def test_fd2_is_restored_and_real_stderr_waits_for_captures(capfd):
    order: list[str] = []
    inside = threading.Event()

    def writer():
        inside.wait()
        with STDERR_LOCK:
            order.append("write")
            _say("to the real stderr\n")

    t = threading.Thread(target=writer)
    t.start()
    with captured("x.dng") as lines:
        inside.set()
        t.join(0.2)  # the writer must still be waiting
        order.append("capture ends")
        _say("x.dng: captured\n")
    t.join()
    assert order == ["capture ends", "write"]
    assert lines == ["x.dng: captured"]
    assert capfd.readouterr().err == "to the real stderr\n"
