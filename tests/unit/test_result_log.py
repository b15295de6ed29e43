"""The run's live log (``results.jsonl``, harness/results.py ResultLog): one whole JSON line per
case however many threads finish cases at once, and a line cut short by an interruption never
swallows the next record."""

from __future__ import annotations

import json
import threading

from fbaconf.harness.results import CaseResult, Outcome, ResultLog


def _result(i: int, size: int) -> CaseResult:
    return CaseResult(case_id=f"s/c{i:04d}", suite="s", claim="simple@1", outcome=Outcome.PASS, message="m" * size)


def test_threads_appending_long_lines_at_once_leave_one_whole_line_each(tmp_path):
    """Lines longer than a write buffer (as a case with 68-value metrics is), eight threads at once:
    before the lock, one appender's check of the last byte could fall inside another's line and
    leave blank or spliced lines (seen in a certified package's results.jsonl)."""
    log = ResultLog(tmp_path / "results.jsonl")
    start = threading.Barrier(8)

    def work(t: int) -> None:
        start.wait()
        for k in range(40):
            log.append(_result(t * 100 + k, 20_000 + 37 * k))

    threads = [threading.Thread(target=work, args=(t,)) for t in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    lines = (tmp_path / "results.jsonl").read_text().split("\n")
    assert lines[-1] == ""  # ends with a newline
    records = [json.loads(x) for x in lines[:-1]]  # no blank line, no spliced line
    assert sorted(r["case_id"] for r in records) == sorted(f"s/c{t * 100 + k:04d}" for t in range(8) for k in range(40))
    assert len(log.read()) == 320


def test_a_line_cut_short_is_skipped_and_the_next_record_starts_a_line(tmp_path):
    p = tmp_path / "results.jsonl"
    log = ResultLog(p)
    log.append(_result(1, 10))
    with open(p, "a") as f:
        f.write('{"case_id": "s/c0002", "sui')  # the run was killed here
    log.append(_result(3, 10))
    assert sorted(log.read()) == ["s/c0001", "s/c0003"]
    assert p.read_text().splitlines()[-1].startswith('{"baseline"')
