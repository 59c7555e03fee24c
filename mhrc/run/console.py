"""Live progress of an episode for a person at a terminal: each robot's action and outcome,
messages between robots, tick summaries, and the final metrics.

Results, messages, thoughts and world events travel on different keys, so they can arrive out
of the order the world published them in. The printer puts them back in tick order: a robot's
thought goes just before its result, and a tick's messages and its "tick N closed" line wait
until every result that tick is known to have (`TickClosed.actions`) has printed."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from pydantic import BaseModel
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys
from mhrc.core.printable import printable
from mhrc.core.protocol import (
    LLM_ERROR_PREFIX,
    ActionResult,
    Communicate,
    EpisodeDone,
    EpisodeStarted,
    Generating,
    ProtocolError,
    RobotAttached,
    RobotDetached,
    RobotMessage,
    ScenarioEvent,
    Thought,
    TickClosed,
    decode,
    decode_event,
)
from mhrc.core.protocol.base import MAX_REQUEST_BYTES
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.protocol.thoughts import MAX_THOUGHT_BYTES, ReplyFailure
from mhrc.core.records import TraceLine, messages

COLORS = {"alice": "magenta", "bob": "cyan", "david": "green"}
# the other robots of a team, in the order they first appear: none used twice while these last
MAX_HELD_THOUGHTS = 10_000  # (tick, robot) pairs whose unparsed reply waits for its result to print before it
PALETTE = ["yellow", "blue", "red", "bright_magenta", "bright_cyan", "bright_green", "bright_yellow", "bright_blue"]

# What the header says of each schedule: up (lockstep) and eval (sequential) give one episode other
# TS, and a person comparing them must see why (docs/schedules.md).
SCHEDULE_GLOSS = {
    "lockstep": "every robot plans on the same state; a sequential run, mhrc eval's default, may take fewer ticks",
    "sequential": "robots act one at a time, each on what the earlier ones left, the paper's",
    "async": "no ticks: TS is the makespan in steps",
}


def inert(text: object) -> str:
    """What a participant or a model wrote, as Rich prints it literally: no markup, no control characters."""
    return escape(printable(text))


@dataclass
class _Tick:
    """What the printer holds back of one tick until its results have printed."""

    closed: str | None = None  # the "tick N closed" line, once the world closed the tick
    due: set[str] = field(default_factory=set)  # robots whose result of this tick has not printed yet
    messages: list[str] = field(default_factory=list)
    senders: set[str] = field(default_factory=set)  # robots whose message of this tick has come
    unheard: set[str] = field(
        default_factory=set
    )  # robots whose message was sent (their result says so) but has not come
    after: list[str] = field(
        default_factory=list
    )  # printed after the closed line: the scenario events of the next tick


class ProgressPrinter:
    """Subscribes to one run's results, messages and world events and prints them in tick order.

    `verbose` False prints only attaches, detaches and the start (`mhrc world`). With `summary`
    the metrics table is printed once the episode ended and the final results it names have
    printed (or at `close()`), after everything held back, and nothing after it; without, the
    caller calls `close()` when the run has returned and prints the table itself (`mhrc up`: no
    table for a run that failed)."""

    def __init__(self, console: Console | None = None, *, verbose: bool = True, summary: bool = True) -> None:
        self.console = console or Console(highlight=False, soft_wrap=True)
        self.verbose = verbose
        self.summary = summary
        self._ticks: dict[int, _Tick] = {}  # ticks with something held back
        self._printed: dict[int, set[str]] = {}  # tick -> robots whose result of it has printed
        self._thoughts: dict[tuple[int, str], list[str]] = {}  # (tick, robot) -> lines, printed before that result
        self._stepped: bool | None = None  # whether ticks close (lockstep, sequential); None: not known yet
        self._last_closed = -1  # the latest tick whose closed line has printed
        self._goals: set[str] = set()  # goal ids of the results printed
        self._done: EpisodeDone | None = None  # with `summary`: the end, its table held until its final results printed
        self._closed = False
        self._colors: dict[str, str] = {}  # robot -> its colour, the paper's own or the next free one

    def attach(self, bus: Bus, run: str) -> None:
        k = Keys(run)
        bus.subscribe(k.world_event, self._on_event)
        bus.subscribe(f"{k.base}/robot/*/action/result", self._on_result)
        bus.subscribe(f"{k.base}/robot/*/inbox/*", self._on_message)
        bus.subscribe(f"{k.base}/agent/*/thought", self._on_thought)
        bus.subscribe(f"{k.base}/agent/*/generating", self._on_generating)

    def mute(self) -> None:
        """Print nothing more, not even what is held back (the run was interrupted: its end is not news)."""
        self._closed = True

    def close(self) -> None:
        """Print everything still held back, in tick order (and with `summary` the table, if the
        episode ended); the printer prints nothing after."""
        if self._closed:
            return
        self._force()
        for lines in self._thoughts.values():
            for line in lines:
                self._print(line)
        self._thoughts.clear()
        self._closed = True
        if self._done is not None:
            self.console.print(summary_table(self._done))

    def _end_when_complete(self) -> None:
        """With `summary`: the table once the episode ended, its final results printed and the
        messages they sent came (each key has its own delivery thread: they may all come after
        `episode_done`)."""
        if self._done is None:
            return
        if not self.verbose or (
            set(self._done.final_results.values()) <= self._goals
            and not any(held.unheard for held in self._ticks.values())
        ):
            self.close()

    def _print(self, line: object) -> None:
        if not self._closed:
            self.console.print(line)

    def _robot(self, name: str) -> str:
        if name not in self._colors:
            taken = set(self._colors.values())
            free = [c for c in PALETTE if c not in taken]
            self._colors[name] = COLORS.get(name) or (free[0] if free else "white")
        return f"[{self._colors[name]}]{inert(f'{name:>5}')}[/]"

    def _tick(self, tick: int) -> _Tick:
        return self._ticks.setdefault(tick, _Tick())

    def _release(self) -> None:
        """Print the held ticks in order, each once it closed and its due results have printed."""
        for tick in sorted(self._ticks):
            held = self._ticks[tick]
            if held.closed is None or held.due or held.unheard:
                return
            self._print_tick(tick)

    def _force(self, upto: int | None = None) -> None:
        """Print every held tick up to `upto` (all with None) now, whatever is still due, then the rest in order."""
        for tick in sorted(t for t in self._ticks if upto is None or t <= upto):
            self._print_tick(tick)
        self._release()

    def _print_tick(self, tick: int) -> None:
        held = self._ticks.pop(tick)
        for robot in sorted(held.due):  # a result that never came: say at least why the robot waited
            for line in self._thoughts.pop((tick, robot), []):
                self._print(line)
        for line in held.messages:
            self._print(line)
        if held.closed is not None:
            self._print(held.closed)
            self._last_closed = max(self._last_closed, tick)
        for line in held.after:
            self._print(line)

    def _on_event(self, sample: Sample) -> None:
        try:
            ev = decode_event(sample.payload)
        except ProtocolError:
            return
        if isinstance(ev, EpisodeStarted):
            self._stepped = ev.scheduler != "async"
            self._print(
                f"[bold]episode {ev.run}[/]: task {ev.task}, scene {ev.scene}, seed {ev.seed}, "
                f"{ev.n_objects} objects, robots {', '.join(ev.robots)}, horizon {ev.horizon}, fidelity {ev.fidelity}"
                + (", noise off" if ev.noise.setting == "off" else "")
                + f", {ev.scheduler} schedule ({SCHEDULE_GLOSS.get(ev.scheduler, 'see docs/schedules.md')})"
            )
        elif isinstance(ev, TickClosed):
            self._stepped = True
            if not self.verbose:
                return
            held = self._tick(ev.tick)
            held.closed = f"[dim]tick {ev.tick:>2} closed: {ev.placed}/{ev.total} placed[/]"
            held.due = set(ev.actions) - self._printed.get(ev.tick, set())
            self._release()
        elif isinstance(ev, RobotAttached):
            self._print(f"{self._robot(ev.robot)} attached (agent {inert(ev.agent_id)}) at tick {ev.tick}")
        elif isinstance(ev, RobotDetached):
            for held in self._ticks.values():  # its results that were due will not come
                held.due.discard(ev.robot)
            self._release()
            self._print(f"{self._robot(ev.robot)} [red]detached[/] at tick {ev.tick}: {inert(ev.reason)}")
        elif isinstance(ev, ScenarioEvent):
            if not self.verbose:
                return
            line = f"[bold yellow]tick {ev.tick:>2} event[/] {inert(ev.text)}"
            if (
                self._stepped and ev.tick - 1 > self._last_closed
            ):  # it fires as its tick opens: after the previous tick's lines
                self._tick(ev.tick - 1).after.append(line)
            else:
                self._print(line)
        elif isinstance(ev, EpisodeDone) and self.summary and self._done is None:
            self._done = ev
            self._end_when_complete()

    def _on_result(self, sample: Sample) -> None:
        if not self.verbose or self._closed:
            return
        try:
            r = decode(sample.payload, ActionResult)
        except ProtocolError:
            return
        if any(t < r.tick and held.closed is not None for t, held in self._ticks.items()):
            self._force(r.tick - 1)  # a later tick's result: what an earlier tick still misses is not coming first
        for line in self._thoughts.pop((r.tick, r.robot), []):
            self._print(line)
        mark = "[green]ok[/]" if r.outcome.succeeded else "[red]failed[/]"
        call = inert(f"{printable(r.action.call()):<34}")
        self._print(f"tick {r.tick:>2} {self._robot(r.robot)} {call} {mark}  [dim]{inert(r.outcome.feedback)}[/]")
        self._printed.setdefault(r.tick, set()).add(r.robot)
        self._goals.add(r.goal_id)
        held = self._ticks.get(r.tick)
        if self._stepped and isinstance(r.action, Communicate) and r.outcome.succeeded and r.tick > self._last_closed:
            held = self._tick(r.tick)
            if r.robot not in held.senders:  # its message goes before the tick's closed line
                held.unheard.add(r.robot)
        if held is not None:
            held.due.discard(r.robot)
            self._release()
        self._end_when_complete()

    def _on_thought(self, sample: Sample) -> None:
        """A reply that gave no action is said so, before the wait it turned into."""
        try:
            t = decode(sample.payload, Thought, max_bytes=MAX_THOUGHT_BYTES)  # not parsed whole past its bound
        except ProtocolError:
            return
        if t.parse_error is None or not self.verbose:
            return
        error = inert(t.parse_error[:200])
        failure = t.failure
        if failure is ReplyFailure.MODEL_UNREACHABLE:
            what = "[red]model unavailable[/]: " + error.removeprefix(LLM_ERROR_PREFIX)
        else:
            cut = " (cut at --max-tokens)" if failure is ReplyFailure.CUT_OFF else ""
            what = f"[red]reply did not parse{cut}[/]: {error}"
        line = f"tick {t.tick:>2} {self._robot(t.robot)} {what}; it waits"
        if t.robot in self._printed.get(t.tick, set()):  # its result came first
            self._print(line)
        elif sample.key.split("/")[-2] == t.robot and (
            (t.tick, t.robot) in self._thoughts or len(self._thoughts) < MAX_HELD_THOUGHTS
        ):  # a robot's own, and a bounded number of them: a login putting thoughts for ticks to come must not grow it
            held = self._thoughts.setdefault((t.tick, t.robot), [])
            if len(held) < 2:  # an agent thinks once a tick (twice if it attached again)
                held.append(line)

    def _on_generating(self, sample: Sample) -> None:
        """A long model call, said as it goes (not held back: it is about now, not a tick's record)."""
        if not self.verbose or self._closed:
            return
        try:
            g = decode(sample.payload, Generating, max_bytes=MAX_REQUEST_BYTES)
        except ProtocolError:
            return
        if g.robot in self._printed.get(g.tick, set()):
            return  # a late status of a step whose result has printed
        what = (
            f"generating ({g.tokens} tokens so far)"
            if g.tokens
            else "waiting for the model's first token (it reads the prompt)"
        )
        again = f", attempt {g.attempt}" if g.attempt > 1 else ""
        self._print(f"[dim]tick {g.tick:>2}[/] {self._robot(g.robot)} [dim]{what}, {g.elapsed:.0f} s{again}[/]")

    def _on_message(self, sample: Sample) -> None:
        if not self.verbose:
            return
        try:
            m = decode(sample.payload, RobotMessage)
        except ProtocolError:
            return
        line = f"        {self._robot(m.sender)} -> {inert(m.to)}: [italic]{inert(m.content)}[/]"
        if self._stepped and m.tick > self._last_closed:  # with the tick it was sent in, after its results
            held = self._tick(m.tick)
            held.messages.append(line)
            held.senders.add(m.sender)
            held.unheard.discard(m.sender)
            self._release()
            self._end_when_complete()
        else:  # async: a message arrives when sent
            self._print(line)


def summary_table(
    done: EpisodeDone,
    recovery: Sequence[Mapping[str, object]] | None = None,
    lost: list[RobotDetached] | None = None,
    protocol: str | None = None,
) -> Table:
    """The episode's metrics for a person; the makespan is the world's clock at the end (README, "Metrics").
    `recovery`: a scenario's events as mhrc.analysis.metrics scores them (`--events`), one row of them;
    `lost`: the robots whose agents left mid-episode and did not come back (mhrc.run.console.lost_robots);
    `protocol`: how the team coordinated (docs/protocols.md), a row only when it is not the paper's, so the
    paper's table stays as it was."""
    m = done.metrics
    t = Table(title=f"episode {inert(done.run)}: {inert(done.reason)}", show_header=False)
    if protocol is not None and protocol != DEFAULT_PROTOCOL:
        t.add_row("protocol", inert(protocol))
    t.add_row("success", "yes" if m.success else "no")
    t.add_row("partial success", f"{m.partial_success:.2f} ({m.placed}/{m.total} placed)")
    bound = f" (no team can need fewer than {m.lower_bound})" if m.lower_bound is not None else ""
    t.add_row("temporal steps", f"{m.temporal_steps}{bound}")
    t.add_row(
        "actions (all robots)",
        f"{m.action_steps} (" + ", ".join(f"{r} {n}" for r, n in m.action_steps_per_robot.items()) + ")",
    )
    t.add_row("failed actions", ", ".join(f"{k} {v}" for k, v in sorted(m.failed_actions.items())) or "none")
    t.add_row("messages", str(m.messages))
    t.add_row("makespan", f"{m.makespan:.1f} s simulated")
    t.add_row("wall time", f"{m.wall_time:.1f} s")
    if recovery:
        t.add_row("scenario events", ", ".join(_recovered(e) for e in recovery))
    if lost:
        t.add_row(
            "[red]robots lost[/]", ", ".join(f"{inert(d.robot)} at tick {d.tick} ({inert(d.reason)})" for d in lost)
        )
    return t


def lost_robots(lines: Iterable[TraceLine]) -> list[RobotDetached]:
    """From a trace (mhrc.core.records.read_records): the robots detached between the start and the end of
    the episode (an agent killed, frozen past its lease, gone) that did not attach again before the end."""
    lost: dict[str, RobotDetached] = {}
    started = False
    for ev in messages(lines, BaseModel):
        if isinstance(ev, EpisodeStarted):
            started = True
        elif isinstance(ev, EpisodeDone):
            break
        elif started and isinstance(ev, RobotDetached):
            lost[ev.robot] = ev
        elif started and isinstance(ev, RobotAttached):
            lost.pop(ev.robot, None)
    return list(lost.values())


def _recovered(e: Mapping[str, object]) -> str:
    where = f"{e['kind']}@{e['tick']}"
    if not e["applied"]:
        return f"{where} skipped"
    steps = e["ticks_to_recover"]
    return f"{where} unrecovered" if steps is None else f"{where} recovered in {steps} step{'s' if steps != 1 else ''}"
