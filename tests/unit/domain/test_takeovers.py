"""What counts as a standby's new takeover, read from its own counters, and the Event's text."""

from __future__ import annotations

from fogfleet.domain.takeovers import (
    MARK_KEEP_SECONDS,
    StandbySeries,
    Takeovers,
    advance_takeovers,
    format_gap,
    new_takeovers,
    record_takeovers,
    takeover_message,
)

WHO = ("bed-robot-1", "human-pose-estimation")


def series(
    count: float, pod: str = "standby-a", created: float = 100.0, **kw: float
) -> StandbySeries:
    return StandbySeries(*WHO, (*WHO, pod), count, created, kw.get("gap"), kw.get("at"))


def test_the_first_reading_is_a_baseline() -> None:
    marks, new = new_takeovers(None, [series(3)], now=0)
    assert new == {} and marks[(*WHO, "standby-a")].count == 3


def test_a_counter_that_rose_counts_its_rise() -> None:
    marks, _ = new_takeovers(None, [series(3)], now=0)
    marks, new = new_takeovers(marks, [series(5, gap=0.41)], now=10)
    assert new[WHO][0] == 2 and new[WHO][1].gap == 0.41
    _, new = new_takeovers(marks, [series(5, gap=0.41)], now=20)
    assert new == {}, "a counter that did not move is no news"


def test_a_restarted_counter_counts_from_zero() -> None:
    marks, _ = new_takeovers(None, [series(3)], now=0)
    # the container restarted and took over once since: lower than before
    _, new = new_takeovers(marks, [series(1, created=200.0)], now=10)
    assert new[WHO][0] == 1
    # restarted and took over as often as before: its created time tells
    _, new = new_takeovers(marks, [series(3, created=200.0)], now=10)
    assert new[WHO][0] == 3


def test_a_new_standby_pod_counts_from_zero() -> None:
    marks, _ = new_takeovers(None, [series(2, pod="old")], now=0)
    _, new = new_takeovers(marks, [series(0, pod="new")], now=10)
    assert new == {}
    _, new = new_takeovers(marks, [series(1, pod="new")], now=10)
    assert new[WHO][0] == 1


def test_a_series_hidden_by_a_cut_goes_on_from_where_it_was() -> None:
    marks, _ = new_takeovers(None, [series(2)], now=0)
    marks, new = new_takeovers(marks, [], now=10)  # cut off: not scraped
    assert new == {} and (*WHO, "standby-a") in marks
    _, new = new_takeovers(marks, [series(3, gap=0.4)], now=300)  # the link is back
    assert new[WHO][0] == 1, "counted once, not from 0 again"
    marks, _ = new_takeovers(marks, [], now=MARK_KEEP_SECONDS + 1)
    assert not marks, "a series gone for a day is forgotten"


def test_one_pod_scraped_by_two_jobs_is_read_once() -> None:
    marks, _ = new_takeovers(None, [series(1)], now=0)
    _, new = new_takeovers(marks, [series(2), series(2)], now=10)
    assert new[WHO][0] == 1


def test_a_record_keeps_the_count_the_last_gap_and_time() -> None:
    got = record_takeovers(None, 1, series(1, gap=0.41, at=1000.0), now=2000.0)
    assert got == Takeovers(1, 0.41, 1000.0)
    got = record_takeovers(got, 2, series(3, gap=0.2), now=3000.0)
    assert got == Takeovers(3, 0.2, 3000.0), "no timestamp from the workload: when it was seen"
    assert record_takeovers(got, 0, series(3, gap=0.2), now=4000.0) is got


def test_a_gap_measured_a_scrape_after_the_counter_fills_in() -> None:
    got = record_takeovers(None, 1, series(1, gap=0.0, at=1000.0), now=1005.0)
    assert got == Takeovers(1, None, 1000.0)
    assert record_takeovers(got, 0, series(1, gap=0.5, at=1000.0), now=1015.0) == Takeovers(
        1, 0.5, 1000.0
    )


def test_advance_updates_records_only_on_news() -> None:
    marks, records = advance_takeovers(None, {}, [series(0)], now=0)
    assert records == {}
    marks, records = advance_takeovers(marks, records, [series(1, gap=0.41, at=5.0)], now=10)
    assert records == {WHO: Takeovers(1, 0.41, 5.0)}
    again = advance_takeovers(marks, records, [series(1, gap=0.41, at=5.0)], now=20)[1]
    assert again == records


def test_the_event_text_names_the_module_the_robot_and_the_gap() -> None:
    assert takeover_message("bed-robot-1", "human-pose-estimation", 1, 0.41) == (
        "the standby of human-pose-estimation on bed-robot-1 took over 0.41 s after the "
        "remote's last output"
    )
    assert "took over 3 times, the last 12 s after" in takeover_message("r", "m", 3, 12.3)
    assert "not measured yet" in takeover_message("r", "m", 1, None)
    assert format_gap(0.405) in ("0.40 s", "0.41 s")
