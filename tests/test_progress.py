"""Progress of long runs (qz_drake.progress): on stderr, a bar on a terminal, plain lines now
and then elsewhere, nothing when disabled; and a simulation watched by it computes what it
computes without it."""

import io
import json
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

from qz_drake.cli import main
from qz_drake.config import load_scenario
from qz_drake.progress import ProgressReport, simulation_progress
from qz_drake.simulation import simulate

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def test_a_log_gets_plain_lines_at_the_interval_and_no_animation():
    log = io.StringIO()
    report = ProgressReport("tune-astar", 40, unit="walks", completed=10, console=Console(file=log), interval=3600)
    assert not report.animated
    report.update(advance=5, status="last: stairs-simple-0 succeeded")
    assert log.getvalue() == ""  # within the interval: nothing yet
    report.interval = 0.0
    report.update(advance=5)
    report.close()
    lines = log.getvalue().splitlines()
    assert len(lines) == 1 and "\x1b" not in lines[0] and "\r" not in lines[0]
    assert lines[0].startswith("tune-astar: 20/40 walks (50 %), last: stairs-simple-0 succeeded, 0:00:00 elapsed")
    # The ETA counts this run's walks only, not the 10 a resumed run found done.
    assert "ETA" in lines[0] and report.eta_seconds() is not None


def test_disabled_is_silent_even_on_a_terminal():
    screen = io.StringIO()
    with ProgressReport("demo", 10, console=Console(file=screen, force_terminal=True), enabled=False) as report:
        report.update(5, status="walking")
    assert screen.getvalue() == ""


def test_a_terminal_gets_a_bar_with_the_amount_and_an_eta():
    screen = io.StringIO()
    with ProgressReport("demo: walking", 300.0, unit="s simulated", digits=1,
                        console=Console(file=screen, force_terminal=True, width=140)) as report:
        assert report.animated
        report.update(12.5, status="3 missions planned")
    assert "demo: walking" in screen.getvalue() and "12.5/300.0 s simulated" in screen.getvalue()
    assert "ETA" in screen.getvalue() and "3 missions planned" in screen.getvalue()


def test_a_bar_is_drawn_by_the_reporting_thread_only():
    # No thread of the bar's own: a garbage collection in another thread would free Drake objects
    # there, off the thread that made them (a make test worker aborted so).
    import threading

    screen = io.StringIO()
    threads = set(threading.enumerate())
    with ProgressReport("walking", 10.0, unit="s", console=Console(file=screen, force_terminal=True, width=100)) as r:
        assert set(threading.enumerate()) == threads
        r.update(4.0)
        drawn = screen.getvalue()
        assert "4/10 s" in drawn
        r.update(5.0)  # within the redraw period: not drawn yet
        r.update(6.0, line_now=True)  # a new stage or a status that must show: drawn at once
        assert "6/10 s" in screen.getvalue()[len(drawn):]


def test_watching_a_simulation_does_not_change_it():
    scenario = load_scenario(SCENARIOS / "stand_flat.yaml")
    plain = simulate(scenario, duration=0.6)
    heard = []
    watched = simulate(scenario, duration=0.6, progress=lambda t, end, missions: heard.append((t, end, missions)))
    np.testing.assert_array_equal(plain.states, watched.states)
    assert heard[-1] == (0.6, 0.6, None)
    assert all(a[0] <= b[0] for a, b in zip(heard, heard[1:]))


@pytest.mark.slow
def test_watching_a_walk_does_not_change_it():
    scenario = load_scenario(SCENARIOS / "walk_flat.yaml")
    plain = simulate(scenario)
    heard = []
    watched = simulate(scenario, progress=lambda t, end, missions: heard.append((t, end, missions)))
    np.testing.assert_array_equal(plain.states, watched.states)
    assert {k: v for k, v in plain.metrics.items() if "time" not in k and "realtime" not in k} == \
        {k: v for k, v in watched.metrics.items() if "time" not in k and "realtime" not in k}
    # The expected end is known once the route is planned; the last call is the walk's end.
    assert heard[-1][0] == heard[-1][1] == pytest.approx(watched.metrics["sim_time_s"])
    assert heard[-1][2] == watched.metrics["missions"]
    assert all(end <= scenario.simulation.duration for _, end, _ in heard)


def test_the_hook_shows_simulated_time_and_missions():
    screen = io.StringIO()
    with ProgressReport("building", console=Console(file=screen, force_terminal=True, width=160)) as report:
        hook = simulation_progress(report, "walking")
        hook(4.0, 20.0, 2)
        assert (report.description, report.completed, report.total) == ("walking", 4.0, 20.0)
        assert report.status == "2 missions planned"
        hook(18.0, 18.0, 5)
        assert report.status == "5 missions planned, writing the results"


def test_the_eta_takes_its_rate_from_the_stage_that_runs(monkeypatch):
    # The demo plans for a while before it walks: an ETA from the whole elapsed time, planning
    # included, was 1.7 times the time left.
    import qz_drake.progress as progress

    clock = [100.0]
    monkeypatch.setattr(progress.time, "perf_counter", lambda: clock[0])
    log = io.StringIO()
    report = ProgressReport("demo: planning", unit="s simulated", console=Console(file=log), interval=3600)
    hook = simulation_progress(report, "demo: walking")
    clock[0] += 20.0  # planning
    hook(0.5, 100.5, 1)
    assert log.getvalue().startswith("demo: walking: 0/100 s simulated (0 %), 1 missions planned, 0:00:20 elapsed")
    clock[0] += 10.0  # 10 s simulated in 10 s
    hook(10.5, 100.5, 3)
    assert report.eta_seconds() == pytest.approx(90.0)


def test_simulate_command_keeps_stdout_json_with_the_bar_on_stderr(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # as on a terminal
    assert main(["simulate", str(SCENARIOS / "stand_flat.yaml"), "--duration", "0.4", "--out", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["sim_time_s"] == 0.4
    assert "simulate stand_flat" in captured.err and "0.4/0.4 s simulated" in captured.err
