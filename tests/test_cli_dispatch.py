"""The command line's dispatch tables: every subcommand the parser lists has a parser builder
and a handler in ``volmc.cli.COMMANDS`` (``volmc.cli.bench.BENCHES`` for ``volmc bench``),
and ``main`` reaches that handler."""

import argparse

import pytest

from volmc import cli
from volmc.cli import bench

#: The least each command needs on the command line to parse.
REQUIRED = {"peer": ["mitsuba"], "bench": ["sparse"], "convert": ["in.npy", "out.vol"]}


def _subcommands(parser):
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return action.choices


def test_tables_cover_every_subcommand():
    commands = _subcommands(cli.build_parser())
    assert list(commands) == list(cli.COMMANDS)
    assert list(_subcommands(commands["bench"])) == list(bench.BENCHES)


@pytest.mark.parametrize("prefix, table", [("", cli.COMMANDS), ("bench_", bench.BENCHES)])
def test_builder_and_handler_sit_together(prefix, table):
    for name, (add, handler) in table.items():
        assert add.__name__ == f"add_{prefix}{name}_parser"
        assert handler.__name__ == f"cmd_{prefix}{name}"
        assert add.__module__ == handler.__module__


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_main_dispatches_each_command(name, monkeypatch):
    seen = []
    add, _ = cli.COMMANDS[name]
    monkeypatch.setitem(cli.COMMANDS, name, (add, lambda args: seen.append(args) or 7))
    assert cli.main([name, *REQUIRED.get(name, [])]) == 7
    assert seen[0].command == name


@pytest.mark.parametrize("name", list(bench.BENCHES))
def test_bench_dispatches_each_benchmark(name, monkeypatch):
    seen = []
    add, _ = bench.BENCHES[name]
    monkeypatch.setitem(bench.BENCHES, name, (add, lambda args: seen.append(args) or 5))
    assert cli.main(["bench", name]) == 5
    assert seen[0].bench == name


def test_unknown_command_is_one_line(capsys):
    assert cli.main(["nosuch"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("volmc: error: command line: argument command: invalid choice")
    assert err.count("\n") == 1


def test_console_script_turns_an_early_ctrl_c_into_the_interrupt_line(monkeypatch, capsys):
    """Found by an outside test: a Ctrl-C in the first half second, while Python imported the
    command line, printed a KeyboardInterrupt traceback. The console script's entry point
    (volmc.console, the one the installed package names) catches it around the import and the
    call, with the interrupt's line and exit status."""
    import sys
    import types
    from importlib.metadata import entry_points
    from volmc import console
    from volmc.cli.common import EXIT_INTERRUPTED
    (script,) = entry_points(group="console_scripts", name="volmc")   # as installed
    assert script.value == "volmc.console:main"

    class Importing(types.ModuleType):
        def __getattr__(self, name):   # the import still running when Ctrl-C comes
            raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "volmc.cli", Importing("volmc.cli"))
    monkeypatch.delattr("volmc.cli", raising=False)
    assert console.main() == EXIT_INTERRUPTED == 130
    assert capsys.readouterr().err == "volmc: interrupted\n"
    monkeypatch.undo()

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "main", interrupted)
    assert console.main() == 130
    assert capsys.readouterr().err == "volmc: interrupted\n"


def test_output_into_a_closed_pipe_ends_quietly():
    """Found by an outside test: `volmc info | head -2` ended in a BrokenPipeError traceback
    when head left first. The console script ends with 141 (128 + SIGPIPE) and says
    nothing. The pipe here is closed before volmc writes its first line."""
    import os
    import subprocess
    import sys
    read, write = os.pipe()
    os.close(read)
    try:
        run = subprocess.run([sys.executable, "-c", "import sys; from volmc.console import "
                              "main; sys.exit(main())", "info"],
                             stdout=write, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert run.returncode == 141, run.stderr
    assert run.stderr == ""
