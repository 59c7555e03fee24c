"""Live progress of an episode for a person at a terminal: each robot's action and outcome,
messages between robots, tick summaries, and the final metrics."""

from __future__ import annotations

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from .bus import Bus, Sample
from .keys import Keys
from .protocol import (
    ActionResult,
    EpisodeDone,
    EpisodeStarted,
    ProtocolError,
    RobotAttached,
    RobotDetached,
    LLM_ERROR_PREFIX,
    RobotMessage,
    Thought,
    TickClosed,
    decode,
    decode_event,
)

COLORS = {"alice": "magenta", "bob": "cyan", "david": "green"}


class ProgressPrinter:
    """Subscribes to one run's results, messages and world events and prints them."""

    def __init__(self, console: Console | None = None, *, verbose: bool = True) -> None:
        self.console = console or Console(highlight=False, soft_wrap=True)
        self.verbose = verbose

    def attach(self, bus: Bus, run: str) -> None:
        k = Keys(run)
        bus.subscribe(k.world_event, self._on_event)
        bus.subscribe(f"{k.base}/robot/*/action/result", self._on_result)
        bus.subscribe(f"{k.base}/robot/*/inbox/*", self._on_message)
        bus.subscribe(f"{k.base}/agent/*/thought", self._on_thought)

    def _robot(self, name: str) -> str:
        return f"[{COLORS.get(name, 'white')}]{name:>5}[/]"

    def _on_event(self, sample: Sample) -> None:
        try:
            ev = decode_event(sample.payload)
        except ProtocolError:
            return
        c = self.console
        if isinstance(ev, EpisodeStarted):
            c.print(
                f"[bold]episode {ev.run}[/]: task {ev.task}, scene {ev.scene}, seed {ev.seed}, "
                f"{ev.n_objects} objects, robots {', '.join(ev.robots)}, horizon {ev.horizon}, fidelity {ev.fidelity}"
                + (f", {ev.scheduler} schedule" if ev.scheduler != "lockstep" else "")
            )
        elif isinstance(ev, TickClosed):
            if self.verbose:
                c.print(f"[dim]tick {ev.tick:>2} closed: {ev.placed}/{ev.total} placed[/]")
        elif isinstance(ev, RobotAttached):
            c.print(f"{self._robot(ev.robot)} attached (agent {ev.agent_id}) at tick {ev.tick}")
        elif isinstance(ev, RobotDetached):
            c.print(f"{self._robot(ev.robot)} [red]detached[/] at tick {ev.tick}: {ev.reason}")
        elif isinstance(ev, EpisodeDone):
            c.print(summary_table(ev))

    def _on_result(self, sample: Sample) -> None:
        if not self.verbose:
            return
        try:
            r = decode(sample.payload, ActionResult)
        except ProtocolError:
            return
        mark = "[green]ok[/]" if r.outcome.succeeded else "[red]failed[/]"
        self.console.print(f"tick {r.tick:>2} {self._robot(r.robot)} {r.action.call():<34} {mark}  [dim]{r.outcome.feedback}[/]")

    def _on_thought(self, sample: Sample) -> None:
        """A reply that gave no action is said so, before the wait it turned into."""
        try:
            t = decode(sample.payload, Thought)
        except ProtocolError:
            return
        if t.parse_error is None or not self.verbose:
            return
        error = escape(t.parse_error[:200])
        if error.startswith(LLM_ERROR_PREFIX):
            what = "[red]model unavailable[/]: " + error.removeprefix(LLM_ERROR_PREFIX)
        else:
            cut = " (cut at --max-tokens)" if t.finish_reason == "length" else ""
            what = f"[red]reply did not parse{cut}[/]: {error}"
        self.console.print(f"tick {t.tick:>2} {self._robot(t.robot)} {what}; it waits")

    def _on_message(self, sample: Sample) -> None:
        if not self.verbose:
            return
        try:
            m = decode(sample.payload, RobotMessage)
        except ProtocolError:
            return
        self.console.print(f"        {self._robot(m.sender)} -> {m.to}: [italic]{m.content}[/]")


def summary_table(done: EpisodeDone) -> Table:
    m = done.metrics
    t = Table(title=f"episode {done.run}: {done.reason}", show_header=False)
    t.add_row("success", "yes" if m.success else "no")
    t.add_row("partial success", f"{m.partial_success:.2f} ({m.placed}/{m.total} placed)")
    bound = f" (no team can need fewer than {m.lower_bound})" if m.lower_bound is not None else ""
    t.add_row("temporal steps", f"{m.temporal_steps}{bound}")
    t.add_row("action steps", f"{m.action_steps} (" + ", ".join(f"{r} {n}" for r, n in m.action_steps_per_robot.items()) + ")")
    t.add_row("failed actions", ", ".join(f"{k} {v}" for k, v in sorted(m.failed_actions.items())) or "none")
    t.add_row("messages", str(m.messages))
    t.add_row("wall time", f"{m.wall_time:.1f} s")
    t.add_row("simulated time", f"{m.sim_time:.1f} s")
    return t
