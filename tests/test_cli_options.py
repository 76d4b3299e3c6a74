"""Shared option groups: one spelling, one default, numbers checked at parse time."""

import argparse

import pytest

from lidarcal.campaign import DEFAULT_BASE_SEED
from lidarcal.cli import build_parser
from lidarcal.cli.options import progress_enabled

SIMULATING = ("calibrate", "simulate", "sweep", "diagnose", "compare")


def _parse(argv):
    return build_parser().parse_args(argv)


def _required(command):
    return {"simulate": ["-o", "x.nc"], "sweep": ["-o", "x.nc"], "diagnose": ["f.nc", "-o", "x.nc"],
            "compare": ["f.nc", "-o", "x.nc"]}.get(
        command, [])


@pytest.mark.parametrize("command", SIMULATING)
def test_simulating_commands_share_one_spelling(command):
    args = _parse([command, *_required(command), "--scheduler", "threads", "--workers", "2", "--chunk", "8",
                   "--cube", "c.nc", "--rwf", "r.nc", "--no-progress"])
    parallel = (args.scheduler, args.workers, args.chunk)
    assert parallel == ("threads", 2, 8) and (args.cube, args.rwf) == ("c.nc", "r.nc")
    assert args.progress is False and progress_enabled(args) is False
    assert args.seed == DEFAULT_BASE_SEED == 20240101


@pytest.mark.parametrize("command", ["calibrate", "simulate", "sweep", "diagnose-generate"])
def test_heights_is_one_list_option(command):
    argv = [command, *_required(command), "--heights", "40", "120.5"]
    if command == "diagnose-generate":
        argv += ["-o", "x.nc"]
    assert _parse(argv).heights == [40.0, 120.5]


@pytest.mark.parametrize("option,value", [("--workers", "0"), ("--chunk", "-3"), ("--chunk", "two")])
def test_bad_numbers_are_refused_at_parse_time(option, value, capsys):
    with pytest.raises(SystemExit) as exc:
        _parse(["simulate", "-o", "x.nc", option, value])
    assert exc.value.code == 2
    assert f"{option} expects a whole number >= 1" in capsys.readouterr().err


def test_progress_follows_the_terminal_unless_forced(monkeypatch):
    class Tty:
        def __init__(self, tty):
            self.tty = tty

        def isatty(self):
            return self.tty

    for tty in (True, False):
        monkeypatch.setattr("sys.stderr", Tty(tty))
        assert progress_enabled(argparse.Namespace(progress=None)) is tty
        assert progress_enabled(argparse.Namespace(progress=True)) is True
        assert progress_enabled(argparse.Namespace(progress=False)) is False
    args = _parse(["calibrate", "--progress"])
    assert args.progress is True


@pytest.mark.parametrize(("option", "value", "problem"), [
    ("--max-replicas", "1e20", "too large"),
    ("--max-replicas", "100000000000000000000", "too large"),  # was "invalid --max-replicas value value"
    ("--max-replicas", "1.5", "not a whole number"),
    ("--max-replicas", "0", "too small"),
    ("--significant-digits", "1000000", "too large"),  # was accepted
    ("--significant-digits", "16", "too large"),
    ("--significant-digits", "two", "not a number"),
])
def test_monte_carlo_bounds_are_refused_with_their_reason(option, value, problem, capsys):
    """Issue 27 §4: --significant-digits had no upper bound; --max-replicas 1e20 gave no reason."""
    import numpy as np

    with pytest.raises(SystemExit) as exc:
        _parse(["calibrate", option, value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "value value" not in err and "Traceback" not in err, err
    bound = {"--max-replicas": "in [1, 10000]", "--significant-digits": "in [1, 15]"}[option]
    assert f"{option} expects a whole number {bound}; got '{value}': {problem} (" in err, err
    assert ("sqrt(replicas)" if option == "--max-replicas" else "float64, which holds 15") in err, err
    assert np.finfo(np.float64).precision == 15  # the digits a float64 holds, the bound's reason


def test_monte_carlo_bounds_take_their_edges_and_float_spelled_whole_numbers():
    args = _parse(["calibrate", "--max-replicas", "1e4", "--significant-digits", "15"])
    assert (args.max_replicas, args.significant_digits) == (10_000, 15)
    assert isinstance(args.max_replicas, int)
