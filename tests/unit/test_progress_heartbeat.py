"""Progress off a terminal (a pipeline step, a CI log): a line at least every ``PLAIN_EVERY_S`` seconds naming the
step, with its share done where it counts its work; paths named as the files will be, never a staging folder."""

from __future__ import annotations

import threading

from foliage_tools.cli import console


def _plain(monkeypatch, every: float) -> tuple[console.RichProgress, list[str], threading.Event]:
    monkeypatch.setattr(console, "PLAIN_EVERY_S", every)
    seen: list[str] = []
    arrived = threading.Event()

    def record(self, text: str) -> None:
        seen.append(text)
        arrived.set()

    monkeypatch.setattr(console.RichProgress, "_print", record)
    p = console.RichProgress(enabled=True)
    p.plain, p.enabled = True, False
    return p, seen, arrived


def test_a_step_that_counts_nothing_still_prints_a_line_while_it_runs(monkeypatch):
    p, seen, arrived = _plain(monkeypatch, 0.2)
    with p:
        p.step("final gather")
        arrived.clear()
        # the main thread is busy (here: waiting) and calls nothing; the heartbeat thread speaks for it
        assert arrived.wait(timeout=10.0), seen
    assert seen[0] == "final gather"
    assert seen[1].startswith("final gather: still running (")


def test_a_counted_step_reports_its_share_done_in_the_heartbeat(monkeypatch):
    p, seen, arrived = _plain(monkeypatch, 0.2)
    with p:
        p.step("tracing", total=8)
        p.advance(2)  # within the interval: no line of its own
        arrived.clear()
        assert arrived.wait(timeout=10.0), seen
    assert any(line.startswith("tracing: 25 % (2/8), running ") for line in seen), seen


def test_no_heartbeat_before_the_interval_and_none_after_the_run(monkeypatch):
    p, seen, _ = _plain(monkeypatch, 3600.0)
    with p:
        p.step("density", total=4)
        p.advance(1)
    assert seen == ["density"]
    assert p._beat is not None and not p._beat.is_alive()


def test_progress_names_outputs_by_their_final_paths_not_the_staging_folder():
    assert console.shown_path("writing out/.tree.bake.tmp-8229-ab12cd34/tree.lb.usda") == "writing out/tree.lb.usda"
    assert console.shown_path("writing /a/b/.x.usda.tmp-1-ff/x.vdb and /a/b/.x.usda.tmp-1-ff/x.usda") == \
        "writing /a/b/x.vdb and /a/b/x.usda"
    # a hidden file of the user's own that merely looks alike (no pid and token) is left as it is
    assert console.shown_path("reading in/.tree.tmp-old/x.usda") == "reading in/.tree.tmp-old/x.usda"
