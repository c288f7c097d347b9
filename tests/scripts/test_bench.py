"""fcmpc-bench's merge of repeated runs: per row the median run, its anchors, and the range."""
from __future__ import annotations

from fcmpc.bench import median_rows


def _run(step_us: float, mc_s: float) -> list[tuple[str, str, str, str]]:
    return [("mission step", f"{step_us} us (p99 {2 * step_us:.0f})", f"baseline: {1000 / step_us:.2f}x", "<= 400 us"),
            ("SITL scenario", "paper_pacific", "", ""),
            ("Monte Carlo", f"{mc_s} s wall", "", "<= 10 s")]


def test_the_median_run_is_shown_with_its_own_anchor_and_the_range():
    merged = median_rows([_run(700.0, 12.1), _run(600.0, 11.7), _run(650.0, 13.0)])
    assert merged[0] == ("mission step", "650.0 us (p99 1300) [600-700, 3 runs]", "baseline: 1.54x", "<= 400 us")
    assert merged[1] == ("SITL scenario", "paper_pacific", "", "")                 # not a number: the first run's
    assert merged[2][1] == "12.1 s wall [11.7-13, 3 runs]"


def test_an_even_count_shows_the_lower_median_and_one_run_is_left_alone():
    assert median_rows([_run(700.0, 12.0), _run(600.0, 11.0)])[0][1].startswith("600.0 us")
    assert median_rows([_run(700.0, 12.0)]) == _run(700.0, 12.0)


def test_a_failed_run_of_a_section_is_shown_as_the_first_run_printed_it():
    failed = [("mission step", "FAILED: RuntimeError: no SITL", "", "")]
    assert median_rows([failed, _run(600.0, 11.0)])[0] == failed[0]
