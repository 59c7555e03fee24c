"""Running a command's coroutine: SIGTERM and Ctrl-C cancel it so every session closes in a
`finally`; a second Ctrl-C quits at once; a bus that cannot start is one line, exit 2."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Callable, Coroutine
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

import click

from mhrc.core.endpoints import BusError
from mhrc.core.lifeline import PARENT_ENV, die_with_parent

if TYPE_CHECKING:  # pragma: no cover
    import asyncio  # imported when a command runs: refusing a command line needs no event loop

T = TypeVar("T")


def quit_now(code: int = 130) -> NoReturn:
    """Quit at once (os._exit: no `finally`, no waiting on threads)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _quit_on_signal(signum: int, frame: Any) -> None:
    """A signal while the run winds down: it is over anyway, so quit at once (130, as Ctrl-C)."""
    quit_now(130)


def _plain_signals(loop: asyncio.AbstractEventLoop) -> None:
    """Take SIGINT and SIGTERM back from the event loop before it closes. asyncio closes its
    self-pipe before it removes its signal handlers; a signal landing in between (a parent's
    SIGTERM right after the group's Ctrl-C) printed "Exception ignored when trying to write to
    the signal wakeup fd" and a traceback."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.remove_signal_handler(sig)  # also clears the wakeup fd once none is left
        child_ctrl_c = sig == signal.SIGINT and os.environ.get(PARENT_ENV)
        signal.signal(sig, signal.SIG_IGN if child_ctrl_c else _quit_on_signal)  # a child keeps ignoring Ctrl-C


def run_command(
    coro_fn: Callable[[], Coroutine[Any, Any, T]],
    *,
    stopping: str | Callable[[], str] | None = None,
    interrupted: Callable[[], str] | None = None,
) -> T:
    """Run a coroutine; SIGTERM cancels it like Ctrl-C, so every session closes in `finally`.
    A child of `mhrc up --processes` or `mhrc eval` gets SIGTERM when its parent dies.

    The first Ctrl-C cancels the run (saying `stopping`, what is being done, when given: a
    callable is asked at that moment); a second one quits at once: the children go with this
    process (mhrc.core.lifeline), never a hang. Once interrupted, one line: `interrupted()` when
    given (where the run's work is), else "interrupted"; a child of `mhrc up --processes` or
    `mhrc eval` says nothing (its parent, interrupted with it, says it once), and takes the
    terminal's Ctrl-C only as the word that the others are about to leave (its warnings about
    them hushed); its parent stops it."""
    import asyncio

    from mhrc.core import logs  # structlog: imported once the command line is accepted

    die_with_parent()

    async def main() -> T:
        task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        if task is not None:

            def on_term() -> None:
                logs.hush()
                task.cancel()

            loop.add_signal_handler(signal.SIGTERM, on_term)
            interrupts = 0

            def on_interrupt() -> None:
                nonlocal interrupts
                interrupts += 1
                if interrupts > 1:
                    sys.stderr.write("interrupted again: quitting at once\n")
                    quit_now(130)
                logs.hush()  # the others leave because of this very Ctrl-C: not news
                said = stopping() if callable(stopping) else stopping
                if said:
                    sys.stderr.write(f"\ninterrupted: {said} (Ctrl-C again to quit at once)\n")
                    sys.stderr.flush()
                task.cancel()

            if not os.environ.get(PARENT_ENV):
                loop.add_signal_handler(signal.SIGINT, on_interrupt)
            else:  # a child: the terminal's Ctrl-C reaches it too, and its parent stops it (SIGTERM); the
                # others leave because of that same Ctrl-C, which may be before this child's SIGTERM comes. Hushed
                # in Python's own handler, at once: a loop's handler waits its turn, and on a loaded machine a
                # teammate stopped by the parent could be seen leaving (and warned of) before that turn came
                signal.signal(signal.SIGINT, lambda signum, frame: logs.hush())
        try:
            return await coro_fn()
        finally:
            if task is not None:
                _plain_signals(loop)

    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        return asyncio.run(main())
    except (KeyboardInterrupt, asyncio.CancelledError):
        if not os.environ.get(PARENT_ENV):
            click.echo(interrupted() if interrupted is not None else "interrupted", err=True)
        sys.exit(130)
    except BusError as exc:  # the bus cannot start (port taken, refused): one line that says what to do
        click.echo(f"mhrc: {exc}", err=True)
        sys.exit(2)
    finally:
        for sig, handler in before.items():  # what the caller had (a test's CliRunner, a later _run)
            signal.signal(sig, handler)
