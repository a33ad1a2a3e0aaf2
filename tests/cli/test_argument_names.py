"""One name and one check for the same thing in every command (skynav/cli_args.py).

The whole parser is built and walked: every sub-command's arguments are compared by what they
hold, so a command that adds ``--seed`` or a dataset positional by hand, under another name or
with another check, fails here.
"""

from __future__ import annotations

import argparse

import pytest

from skynav import cli_args
from skynav.cli import build_parser, main


def _commands(parser, prefix=()):
    """(words, parser) of every leaf command."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    for name, child in subs[0].choices.items():
        yield from _commands(child, prefix + (name,))


COMMANDS = dict((" ".join(words), p) for words, p in _commands(build_parser()))


def _actions(dest):
    return [(name, a) for name, p in COMMANDS.items() for a in p._actions if a.dest == dest]


def test_the_walk_sees_every_command():
    assert {"render", "scene", "dataset generate", "dataset verify", "hil export", "calibrate geometric",
            "bench ip", "bench nav", "bench loop", "serve"} <= set(COMMANDS)


def test_a_dataset_is_always_the_DATASET_positional():
    takes = {name for name, a in _actions("dataset")}
    assert {"dataset verify", "dataset info", "dataset preview", "bench ip", "bench nav", "hil export"} <= takes
    for name, a in _actions("dataset"):
        assert not a.option_strings and a.metavar == "DATASET", name
    for name, p in COMMANDS.items():   # the former names of the same positional
        assert not {a.dest for a in p._actions if not a.option_strings} & {"path", "dir"}, name


def test_seeds_workers_and_the_facility_have_one_spelling_and_one_check():
    for name, a in _actions("seed"):
        assert a.option_strings == ["--seed"] and a.type is cli_args.seed_int, name
    workers = _actions("workers")
    assert {n for n, _ in workers} >= {"dataset generate", "hil export", "bench nav", "bench loop", "serve"}
    for name, a in workers:
        assert a.option_strings == ["--workers"], name
        assert a.type("1") == 1 and a.type(str(cli_args.MAX_WORKERS)) == cli_args.MAX_WORKERS, name
        for bad in ("0", str(cli_args.MAX_WORKERS + 1), "two"):
            with pytest.raises(argparse.ArgumentTypeError):
                a.type(bad)
    shown = [(n, a) for n, a in _actions("facility") if a.help is not argparse.SUPPRESS]
    assert {n for n, _ in shown} >= {"render", "hil facility", "hil export", "calibrate patterns", "serve"}
    for name, a in shown:
        assert a.option_strings == ["--facility"] and a.metavar == "FACILITY", name
    for name, p in COMMANDS.items():
        outputs = [a for a in p._actions if a.dest == "output"]
        assert all(a.option_strings == ["-o", "--output"] for a in outputs), name


@pytest.mark.parametrize("argv", [
    ["render", "--seed", "-1"], ["dataset", "generate", "montecarlo", "-o", "x", "--seed", "-1"],
    ["bench", "loop", "sequence", "-o", "x", "--seed", "-1"], ["calibrate", "simulate", "--facility", "screen_small",
                                                                "--patterns", "p", "-o", "x", "--seed", "-1"],
])
def test_a_bad_seed_is_the_same_line_everywhere(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1
    assert "argument --seed: -1: expected an integer in 0..9223372036854775807" in err, err
    assert not (tmp_path / "x").exists()


def test_the_former_spellings_are_read_and_must_agree(tmp_path, capsys, monkeypatch):
    """``render --hil F`` and ``calibrate STEP F`` (documented before --facility) still work; given
    with --facility they must name the same facility."""
    monkeypatch.chdir(tmp_path)
    assert main(["hil", "facility", "screen_small", "-o", "a.yaml", "-q"]) == 0
    assert main(["hil", "facility", "--facility", "screen_small", "-o", "b.yaml", "-q"]) == 0
    assert (tmp_path / "a.yaml").read_bytes() == (tmp_path / "b.yaml").read_bytes()
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "patterns", "screen", "--facility", "screen_small", "-o", "p"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and "give the facility once, as --facility" in err
    assert main(["calibrate", "patterns", "-o", "p"]) == 2
    assert "required: --facility FACILITY" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()
