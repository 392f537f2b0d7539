"""``gonio console``: the operator's verbs in a shell on one open connection to the rig.

Each line is parsed by the same argparse sub-parsers as the one-shot commands (without the
options that open the rig): ``jog light_theta 5``, ``move --theta-i 30 --theta-r 30
--delta-phi 180``, ``status --json``, ``torque off camera_phi``; a leading ``gonio`` is ignored,
so the commands error messages suggest can be pasted. Errors print one ``gonio: error: …`` line
and the shell goes on. On a simulated rig the one simulator lives for the whole session, so
state persists from line to line.

At a terminal: a prompt, readline history (``$XDG_STATE_HOME/gonio/console_history``, default
``~/.local/state/gonio/``; a missing or read-only home only loses the history), tab completion
of verbs, options and axis names, ``help`` / ``help VERB``, ``quit`` / ``exit`` / Ctrl-D.
Ctrl-C during a command stops every axis (torque stays on) and returns to the prompt; a second
Ctrl-C during the same command exits at once (:func:`acquisition.api.sigint_stops_motion`).

When stdin is not a terminal the lines are a script: no prompt, ``#`` comments and blank lines
skipped, and the exit status is that of the last line that failed (0 when none did).
"""

from __future__ import annotations

import argparse
import cmd
import os
import shlex
import sys
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any, NoReturn

from acquisition import api
from acquisition.cli.console import VERB_HELP, VERBS, add_verbs

EXIT_INTERRUPTED = 130
"""Exit status of a line (or a script) ended by Ctrl-C, as for the one-shot commands."""

HISTORY_LENGTH = 1000
"""Lines of history kept."""

_AXIS_ARGS = {"jog": "one", "reboot": "one", "home": "many", "torque": "many"}
"""Verbs whose positional arguments are axis names (``torque`` after on/off)."""

_SHELL_WORDS = {"help": "help [VERB]: the verbs, or one verb's options",
                "quit": "quit (or exit, or Ctrl-D): close the connection and leave"}


class ShellUsageError(Exception):
    """A line the verb's parser refuses (the message is argparse's)."""


class _ParserExit(Exception):
    """The parser wanted to exit (after ``-h``): back to the prompt."""


class ShellParser(argparse.ArgumentParser):
    """An argument parser that raises instead of exiting the process."""

    def error(self, message: str) -> NoReturn:
        raise ShellUsageError(f"{self.prog}: {message}")

    def exit(self, status: int = 0, message: str | None = None) -> NoReturn:
        if message:
            self._print_message(message, sys.stderr)
        raise _ParserExit(status)


def verb_parsers() -> dict[str, argparse.ArgumentParser]:
    """``{verb: parser}`` for a connected shell (the one-shot grammar without ``--rig`` etc.)."""
    sub = ShellParser(prog="gonio", add_help=False).add_subparsers(dest="command")
    add_verbs(sub, connection=False)
    parsers = dict(sub.choices)
    for name, parser in parsers.items():
        parser.prog = name
    return parsers


def history_path() -> Path:
    """Where the console's readline history lives."""
    state = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local",
                                                             "state")
    return Path(state) / "gonio" / "console_history"


@contextmanager
def readline_history(path: Path) -> Iterator[None]:
    """Load the history from ``path`` and save it back afterwards; without ``readline``, or
    when the file cannot be read or written, the session simply has none."""
    try:
        import readline
    except ImportError:  # pragma: no cover - Python built without readline
        yield
        return
    delims = readline.get_completer_delims()
    readline.set_completer_delims(" \t\n")  # axis names and --options complete whole
    readline.set_history_length(HISTORY_LENGTH)
    with suppress(OSError):
        readline.read_history_file(path)
    try:
        yield
    finally:
        readline.set_completer_delims(delims)
        with suppress(OSError):
            path.parent.mkdir(parents=True, exist_ok=True)
            readline.write_history_file(path)


class ConsoleShell(cmd.Cmd):
    """The verbs of :data:`acquisition.cli.console.VERBS` on one open :class:`api.Console`.

    Parameters
    ----------
    console:
        The open rig.
    stdin, stdout:
        Where lines come from and output goes (default: ``sys.stdin`` / ``sys.stdout``).
    interactive:
        Prompt and readline (default: stdin is a terminal).
    json_output:
        Every verb reports one JSON object (as if each line had ``--json``).
    """

    intro = None

    def __init__(self, console: api.Console, *, stdin: IO[str] | None = None,
                 stdout: IO[str] | None = None, interactive: bool | None = None,
                 json_output: bool = False) -> None:
        stdin = sys.stdin if stdin is None else stdin
        stdout = sys.stdout if stdout is None else stdout
        super().__init__(stdin=stdin, stdout=stdout)
        self.console = console
        self.interactive = stdin.isatty() if interactive is None else interactive
        self.use_rawinput = self.interactive
        self.prompt = "gonio> " if self.interactive else ""
        self.json_output = json_output
        self.parsers = verb_parsers()
        self.exit_status = 0
        """The exit code of the last line that failed (0 while none has)."""

    # ------------------------------------------------------------------ running
    def run(self) -> int:
        """Read and run lines until quit/exit/EOF; returns the session's exit status (at a
        terminal 0, for a script that of the last line that failed)."""
        if not self.interactive:
            self._loop()
            return self.exit_status
        rig = self.console.rig
        self._say(f"gonio console: {rig.name} ({rig.path}), axes {', '.join(self.console.axis_names)}"
                  "; help lists the verbs, quit leaves")
        with readline_history(history_path()):
            self._loop()
        return 0

    def _loop(self) -> None:
        while True:
            try:
                self.cmdloop()
                return
            except KeyboardInterrupt:  # Ctrl-C at the prompt: a fresh prompt, as in a shell
                if not self.interactive:
                    self.exit_status = EXIT_INTERRUPTED
                    return
                self._say("^C")

    def _say(self, text: str) -> None:
        print(text, file=self.stdout, flush=True)

    def fail(self, message: str, code: int = 2) -> None:
        """One ``gonio: error: …`` line on stderr; the session goes on."""
        print(f"gonio: error: {message}", file=sys.stderr, flush=True)
        self.exit_status = code or 2

    def run_verb(self, verb: str, line: str) -> None:
        """Parse ``line`` with the verb's parser and run it on the open console."""
        try:
            args = self.parsers[verb].parse_args(shlex.split(line))
        except ShellUsageError as exc:
            self.fail(str(exc))
            return
        except _ParserExit:
            return
        except ValueError as exc:  # shlex: an unclosed quote
            self.fail(f"{verb}: {exc}")
            return
        args.command = verb
        args.json = args.json or self.json_output
        try:
            with api.sigint_stops_motion():
                code = VERBS[verb](self.console, args)
        except api.GonioError as exc:
            self.fail(str(exc), exc.exit_code)
        except KeyboardInterrupt:  # Ctrl-C outside a move: stop the axes anyway
            stopped = "all axes stopped"
            try:
                self.console.stop()
            except api.GonioError as exc:
                stopped = f"stopping the axes failed ({exc})"
            self.fail(f"{verb}: interrupted: {stopped}; `status` shows where",
                      EXIT_INTERRUPTED)
        else:
            if code:
                self.exit_status = code

    # ------------------------------------------------------------------ cmd hooks
    def precmd(self, line: str) -> str:
        words = line.strip()
        if words.startswith("#"):
            return ""
        if words == "gonio" or words.startswith("gonio "):
            words = words[len("gonio"):].strip()
        return words

    def emptyline(self) -> bool:
        return False  # never repeat the last command (it may have been a move)

    def default(self, line: str) -> bool:
        verb = line.split()[0]
        self.fail(f"unknown command '{verb}': the verbs are {', '.join(VERBS)} (help, quit)")
        return False

    def do_status(self, line: str) -> None:
        self.run_verb("status", line)

    def do_scan(self, line: str) -> None:
        self.run_verb("scan", line)

    def do_jog(self, line: str) -> None:
        self.run_verb("jog", line)

    def do_move(self, line: str) -> None:
        self.run_verb("move", line)

    def do_home(self, line: str) -> None:
        self.run_verb("home", line)

    def do_park(self, line: str) -> None:
        self.run_verb("park", line)

    def do_torque(self, line: str) -> None:
        self.run_verb("torque", line)

    def do_reboot(self, line: str) -> None:
        self.run_verb("reboot", line)

    def do_quit(self, line: str) -> bool:
        return True

    do_exit = do_quit

    def do_EOF(self, line: str) -> bool:  # noqa: N802 - the name cmd gives end of input
        if self.interactive:
            self._say("")
        return True

    def do_help(self, line: str) -> None:
        """``help``: every verb with its one-line help; ``help VERB``: the verb's options."""
        name = line.strip()
        if not name:
            width = max(map(len, (*VERB_HELP, *_SHELL_WORDS)))
            self._say("verbs (help VERB shows its options):")
            for verb, text in VERB_HELP.items():
                self._say(f"  {verb.ljust(width)}  {text}")
            for word, text in _SHELL_WORDS.items():
                self._say(f"  {word.ljust(width)}  {text}")
        elif name in self.parsers:
            self._say(self.parsers[name].format_help().rstrip())
        elif name in ("quit", "exit", "help"):
            self._say(_SHELL_WORDS["help" if name == "help" else "quit"])
        else:
            self.fail(f"help: no verb '{name}': the verbs are {', '.join(VERBS)}")

    # ------------------------------------------------------------------ completion
    def completenames(self, text: str, *ignored: Any) -> list[str]:
        words = [*VERBS, "help", "quit", "exit"]
        return [w for w in words if w.startswith(text)]

    def complete_help(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return [v for v in VERBS if v.startswith(text)]

    def _complete_args(self, verb: str, text: str, line: str, begidx: int) -> list[str]:
        """Candidates for the word being typed: the verb's options after ``-``, else its
        positional choices (axis names not yet given; ``on``/``off`` for torque)."""
        parser = self.parsers[verb]
        if text.startswith("-"):
            options = [o for a in parser._actions for o in a.option_strings]
            return [o for o in options if o.startswith(text)]
        before = [w for w in line[:begidx].split()[1:] if not w.startswith("-")]
        if verb == "torque" and not before:
            choices = ["on", "off"]
        elif _AXIS_ARGS.get(verb) == "one" and not before:
            choices = self.console.axis_names
        elif _AXIS_ARGS.get(verb) == "many":
            choices = [a for a in self.console.axis_names if a not in before]
        else:
            choices = []
        return [c for c in choices if c.startswith(text)]

    def complete_status(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("status", text, line, begidx)

    def complete_scan(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("scan", text, line, begidx)

    def complete_jog(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("jog", text, line, begidx)

    def complete_move(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("move", text, line, begidx)

    def complete_home(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("home", text, line, begidx)

    def complete_park(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("park", text, line, begidx)

    def complete_torque(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("torque", text, line, begidx)

    def complete_reboot(self, text: str, line: str, begidx: int, endidx: int) -> list[str]:
        return self._complete_args("reboot", text, line, begidx)


def run_shell(console: api.Console, *, json_output: bool = False) -> int:
    """Run :class:`ConsoleShell` on stdin/stdout; returns its exit status."""
    return ConsoleShell(console, json_output=json_output).run()
