"""The session log survives torn lines: read skips them, append starts fresh, repair keeps records."""

import json
import warnings

import numpy as np
import pytest

from touchloc.errors import ValidationError
from touchloc.hardware import (SessionLog, TornRecordWarning, check_session, read_session,
                               repair_session)
from touchloc.models import Contacts
from touchloc.planners import GuardedTouch, TouchResult

T = GuardedTouch((0, 0, 0.1), (0, 0, -1), 0.05, name="down")
FRAGMENT = '{"format":"touchloc-session/1","touch":{"orig'


def _write(p, zs):
    with SessionLog(p) as log:
        for z in zs:
            log.append(TouchResult(T, 0.1 - z, Contacts([[0, 0, z]], [[0, 0, 1]])), z=z)


def _zs(records):
    return [r.extra["z"] for r in records]


def test_torn_line_then_restart_keeps_every_record(tmp_path):
    p = tmp_path / "s.jsonl"
    _write(p, [0.08, 0.07])
    with open(p, "a") as fh:
        fh.write(FRAGMENT)                       # crash mid-write
    _write(p, [0.06, 0.05])                      # restart appends
    text = p.read_text()
    assert text.splitlines()[2] == FRAGMENT      # the fragment stays on a line of its own
    with pytest.warns(TornRecordWarning, match="line.*3"):
        recs = read_session(p)
    assert _zs(recs) == [0.08, 0.07, 0.06, 0.05]
    chk = check_session(p)
    assert chk.torn == [3] and len(chk.records) == 4

    assert repair_session(p) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # no torn lines any more
        assert _zs(read_session(p)) == [0.08, 0.07, 0.06, 0.05]
    assert repair_session(p) == 0
    np.testing.assert_allclose(read_session(p)[2].result.contact.points, [[0, 0, 0.06]])


def test_fragment_glued_to_a_record_by_an_older_writer_is_recovered(tmp_path):
    p = tmp_path / "s.jsonl"
    _write(p, [0.08])
    whole = p.read_text()
    p.write_text(whole + FRAGMENT + whole)      # no fresh line before the next record
    with pytest.warns(TornRecordWarning):
        assert _zs(read_session(p)) == [0.08, 0.08]


def test_whole_record_missing_only_its_line_end_is_kept(tmp_path):
    p = tmp_path / "s.jsonl"
    _write(p, [0.08, 0.07])
    p.write_text(p.read_text().rstrip("\n"))
    assert _zs(read_session(p)) == [0.08, 0.07]
    _write(p, [0.06])
    assert _zs(read_session(p)) == [0.08, 0.07, 0.06]


def test_complete_lines_that_are_not_records_are_errors(tmp_path):
    p = tmp_path / "s.jsonl"
    _write(p, [0.08])
    rec = json.loads(p.read_text())
    del rec["touch"]
    p.write_text(json.dumps(rec) + "\n")
    with pytest.raises(ValidationError, match="line 1"):
        read_session(p)
    p.write_text('{"format": "other/2"}\n')
    with pytest.raises(ValidationError, match="format"):
        read_session(p)
    with pytest.raises(ValidationError):
        repair_session(tmp_path)                 # a directory
    with pytest.raises(ValidationError):
        read_session(True)


def test_kill_9_of_a_writer_loses_no_acknowledged_record(tmp_path):
    """A few real SIGKILL cycles (benchmarks/bench_reliability.py runs 100)."""
    from touchloc.hardware.emulator._crash import kill_cycles

    r = kill_cycles(tmp_path / "s.jsonl", 4, rng=3, chunked=0.75)
    assert r["acked"] > 0
    assert r["lost"] == 0 and r["lost_by_repair"] == 0
    assert r["torn_after_repair"] == 0 and r["after_repair"] >= r["acked"]


def test_kill_9_of_forked_writers_loses_no_acknowledged_record(tmp_path):
    """The same writer forked (no interpreter start): more cycles in the same time."""
    from touchloc.hardware.emulator._crash import kill_cycles

    r = kill_cycles(tmp_path / "s.jsonl", 12, rng=5, chunked=0.75, start="fork")
    assert r["cycles"] == 12 and r["acked"] > 0
    assert r["lost"] == 0 and r["lost_by_repair"] == 0
    assert r["torn_after_repair"] == 0 and r["after_repair"] >= r["acked"]
