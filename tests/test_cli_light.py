"""A typo on the command line is refused before the heavy imports (issue 43): the simulator, the
bus, plotting, Ray and the model clients stay unimported, checked in a fresh interpreter's
sys.modules (never by the clock); task, scene, team and command names get near matches."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from mhrc.cli import COMMANDS, main
from mhrc.cli import names as cli_names
from mhrc.core.endpoints import free_port

HEAVY = ("pybullet", "zenoh", "matplotlib", "ray", "xllamacpp", "httpx", "openai", "mhrc.agents.llm.openai_client")
HEAVY += ("structlog", "cryptography", "asyncio")  # the logs, the secured bus, the event loop: a run's, not a refusal's

PROBE = """
import json, sys
from mhrc.cli import main
try:
    main(sys.argv[1:], prog_name="mhrc")
except SystemExit as exc:
    code = exc.code
print(json.dumps({"code": code, "heavy": sorted(m for m in HEAVY if m in sys.modules)}))
"""


def _refused(*args: str, heavy: tuple[str, ...] = HEAVY) -> tuple[dict[str, object], str]:
    done = subprocess.run(
        [sys.executable, "-c", f"HEAVY = {heavy!r}\n{PROBE}", *args], capture_output=True, text=True, timeout=120
    )
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["upp"], "Did you mean 'up'?"),
        (["up", "--horizn", "3"], "Did you mean one of: '--horizon'"),
        (["up", "--task", "pack_objetcs"], "unknown task 'pack_objetcs' (did you mean 'pack_objects'?)"),
        (["up", "--scene", "kitchn"], "unknown scene 'kitchn' (did you mean 'kitchen'?)"),
        (["up", "--team", "ful_house"], "did you mean 'full_house'?"),
        (["world", "--task", "sort_solid"], "(did you mean 'sort_solids'?)"),
        (["agent", "--robot", "bob", "--connect", "tcp/127.0.0.1:9", "--team", "larg"], "did you mean 'large'?"),
        (["up", "--objects", "many"], "'many' is not a valid integer"),
        (["eval", "--tasks", "pack_objects,sort_solid"], "unknown task 'sort_solid' (did you mean 'sort_solids'?)"),
        (["eval", "--scenes", "kitchen,kitchn"], "unknown scene 'kitchn' (did you mean 'kitchen'?)"),
        (["eval", "--trails", "2"], "'--trials'"),
        (["eval", "--team", "paper", "--team", "ful_house"], "did you mean 'full_house'?"),
        (["eval", "--schedule", "lockstp"], "'lockstp' is not one of"),
        (["up", "--protocol", "centraliz"], "unknown protocol 'centraliz' (did you mean 'centralized'?)"),
        (["eval", "--protocol", "mhrc,leder"], "unknown protocol 'leder' (did you mean 'leader'?)"),
        (["agent", "--robot", "bob", "--connect", "tcp/127.0.0.1:9", "--protocol", "lead"], "did you mean 'leader'?"),
    ],
    ids=[
        *("command", "option", "task", "scene", "team", "world-task", "agent-team", "bad-int"),
        *("eval-task", "eval-scene", "eval-option", "eval-team", "eval-schedule"),
        *("up-protocol", "eval-protocol", "agent-protocol"),
    ],
)
def test_a_typo_is_refused_in_one_line_before_any_heavy_import(args: list[str], said: str) -> None:
    got, stderr = _refused(*args)
    assert got["code"] == 2, stderr
    assert said in stderr, stderr
    assert got["heavy"] == [], f"{' '.join(args)} imported {got['heavy']} before refusing"
    assert "Traceback" not in stderr


@pytest.mark.parametrize("args", [["--help"], ["up", "--help"], ["eval", "--help"], ["agent", "--help"]])
def test_help_imports_no_command_it_does_not_show_nor_the_wire(args: list[str]) -> None:
    """`mhrc --help` lists the commands from their one-line help (cli.SUMMARIES), so it imports
    none of their modules; a command's --help imports its options only: no wire models, no logs."""
    got, stderr = _refused(*args, heavy=(*HEAVY, "pydantic", "mhrc.core.protocol", "mhrc.cli.bustools"))
    assert got["code"] == 0, stderr
    assert got["heavy"] == [], f"{' '.join(args)} imported {got['heavy']}"


SIMULATOR = ("pybullet", "ompl", "mhrc.world.sim", "mhrc.world.robots", "mhrc.world.arm", "mhrc.world.scene")
# the wire's models, the protocols' registry, the schedulers (asyncio with them): the configuration
# reads the default protocol, the schedules' and the aids' names from light modules (mhrc.core.coordination,
# mhrc.world.schedules, mhrc.core.aids)
WIRE = ("mhrc.core.protocol", "mhrc.agents.protocols", "mhrc.world.schedulers", "asyncio")
# the layouts' models, the tasks and numpy (a team's room on the map): --scene is checked against the layout
# files' names (mhrc.world.scene_files), and a team's kinds before the registries are imported
REGISTRIES = ("mhrc.world.layouts", "mhrc.world.tasks", "numpy")
BUS = ("zenoh", "mhrc.core.bus", "mhrc.core.trace", "rich")  # the bus, the trace and the console: a run's


@pytest.mark.parametrize(
    ("args", "code", "heavy"),
    [
        (["up", "--team", "alice=mobile_manipulator,david=mobile_base"], 2, (*SIMULATOR, *BUS, *WIRE, *REGISTRIES)),
        (["up", "--objects", "9"], 2, (*SIMULATOR, *BUS, *WIRE, *REGISTRIES)),
        (["eval", "--trials", "0"], 2, (*SIMULATOR, *BUS, *WIRE, *REGISTRIES, "matplotlib", "mhrc.eval.engine")),
        (["teams"], 0, (*SIMULATOR, "numpy")),
        (["scenes"], 0, (*SIMULATOR, "numpy")),
    ],
    ids=["up-team", "up-objects", "eval-trials", "teams", "scenes"],
)
def test_a_value_checked_against_the_world_needs_no_simulator(
    args: list[str], code: int, heavy: tuple[str, ...]
) -> None:
    """Past the names, a value is checked against the world's data (its robot kinds, layouts,
    tasks, a team's room on the map), never its simulator: the kinds, layouts, tasks and occupancy
    grid import no PyBullet or OMPL, and what needs no grid no numpy either; nor does a refusal
    import the bus, the trace, the console or the evaluation's engine, and a value refused by the
    configuration's fields or by a team's kinds neither the wire's models nor the layouts (issue 46
    item 4)."""
    got, stderr = _refused(*args, heavy=heavy)
    assert got["code"] == code, stderr
    assert got["heavy"] == [], f"{' '.join(args)} imported {got['heavy']}"
    assert "Traceback" not in stderr


# what a heuristic episode on the open bus never uses: the model clients (httpx), the LLM policy and
# replays, the other protocols' planners, the certificates (cryptography)
UNUSED = ("httpx", "cryptography", "mhrc.agents.llm.openai_client", "mhrc.agents.llm.local", "mhrc.agents.llm_policy")
UNUSED += ("mhrc.agents.protocols.centralized_llm", "mhrc.agents.protocols.leader_llm", "mhrc.core.security")
# and structlog with rich's tracebacks and pygments behind it: nothing is logged at the default level, and
# mhrc.core.logs imports structlog when a line is first due
UNUSED += ("structlog", "pygments")


def test_a_heuristic_run_on_the_open_bus_imports_no_model_client_nor_cryptography(tmp_path: object) -> None:
    """`mhrc up --insecure` with the heuristic team, to the end of one tick (issue 46 item 4: its
    start-up): the modules it has no use for stay unimported, they were a fifth of its imports (and
    structlog a tenth of its start)."""
    got, stderr = _refused(
        *("up", "--horizon", "1", "--quiet", "--insecure", "--trace", f"{tmp_path}/trace.jsonl"), heavy=UNUSED
    )
    assert got["code"] in (0, None), stderr
    assert got["heavy"] == [], f"mhrc up imported {got['heavy']}"


LOGS = """
import io, json, sys
from mhrc.core import logs
log = logs.get_logger("mhrc.probe").bind(run="r1")
log.debug("below the level")
before = "structlog" in sys.modules
log.warning("a robot left", robot="bob")
import structlog
from structlog.testing import LogCapture
seen = LogCapture()  # another set-up than mhrc's, at debug: it gets every line, whatever mhrc's level
structlog.configure(processors=[seen], wrapper_class=structlog.make_filtering_bound_logger(10))
logs.get_logger("mhrc.other").bind(run="r2").debug("for the test")
logs.configure("warning")  # mhrc's again, at once now that structlog is imported
logs.get_logger("mhrc.other").info("below the level again")
print(json.dumps({"before": before, "seen": seen.entries, "installed": structlog.get_config()["processors"] is logs._installed}))
"""


def test_a_line_below_the_level_leaves_structlog_unimported_and_a_line_due_prints_as_before() -> None:
    """mhrc.core.logs imports structlog when a line is first due: a debug line at the default level
    (warning) does not import it; a warning does, installs mhrc's set-up and prints its usual line
    on stderr (time, level, event, its bound and given context); a configuration that is not mhrc's
    (a library user's) gets every line, whatever mhrc's level."""
    done = subprocess.run([sys.executable, "-c", LOGS], capture_output=True, text=True, timeout=120)
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["before"] is False and got["installed"] is True
    assert got["seen"] == [{"run": "r2", "event": "for the test", "log_level": "debug"}]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert "[warning  ] a robot left" in lines[0] and "robot=bob" in lines[0] and "run=r1" in lines[0], lines


def test_the_command_list_is_what_click_would_list_from_the_commands_themselves() -> None:
    import click

    ctx = click.Context(main)
    for width in (50, 80, 120):
        ours, clicks = click.HelpFormatter(width=width), click.HelpFormatter(width=width)
        main.format_commands(ctx, ours)
        click.Group.format_commands(main, ctx, clicks)  # imports every command's module
        assert ours.getvalue() == clicks.getvalue()


def test_the_light_lists_are_the_registries() -> None:
    """names.py lists tasks, teams and protocols because their registries cost more than a typo should; they must agree."""
    from mhrc.run.config import SCHEDULES
    from mhrc.world.tasks import TASKS
    from mhrc.world.teams import SHIPPED

    assert cli_names.TASKS == tuple(TASKS)
    assert cli_names.TEAMS == tuple(SHIPPED)
    from mhrc.agents.protocols import PROTOCOLS

    assert cli_names.PROTOCOLS == tuple(PROTOCOLS)
    from mhrc.cli.options import SCHEDULES as OPTION_SCHEDULES
    from mhrc.world.schedulers import SCHEDULERS

    assert OPTION_SCHEDULES == SCHEDULES == tuple(SCHEDULERS)  # one light list (world/schedules.py), the registry's
    from mhrc.world.layouts import LAYOUTS
    from mhrc.world.scene_files import scene_files

    assert list(scene_files()) == list(LAYOUTS) and "kitchen" in LAYOUTS  # --scene's names, without a layout read


def test_every_command_loads_under_its_name() -> None:
    import click

    ctx = click.Context(main)
    for name in COMMANDS:
        command = main.get_command(ctx, name)
        assert command is not None and command.name == name, name
    assert main.list_commands(ctx) == sorted(COMMANDS)


def test_a_team_file_or_inline_team_is_not_taken_for_a_typo(tmp_path: object) -> None:
    assert cli_names.unknown_team("alice=mobile_manipulator,bob=tabletop_arm") is None
    assert cli_names.unknown_team("mine.toml") is None and cli_names.unknown_team("full_house") is None
    assert "not a shipped team (paper, no_mobile" in (cli_names.unknown_team("nosuchteam") or "")


def test_each_command_module_is_named_after_a_command_it_holds() -> None:
    """Issue 44: `mhrc up` is in cli/up.py, `mhrc doctor` in cli/doctor.py; only the viewer's module
    holds a group (`scenes`, `render`, `show`) under the group's name."""
    modules = {module for module, _ in COMMANDS.values()}
    assert modules - set(COMMANDS) == {"viewer"}
    for name, (module, _) in COMMANDS.items():
        assert module == name or name in {"report", "scenes", "render", "show"}, (name, module)


def test_mhrc_protocols_lists_each_protocol_in_one_line() -> None:
    from click.testing import CliRunner

    from mhrc.agents.protocols import PROTOCOLS

    out = CliRunner().invoke(main, ["protocols"])
    assert out.exit_code == 0 and out.output.splitlines() == [p.line() for p in PROTOCOLS.values()]


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="the ray extra is not installed")
def test_a_ray_address_nothing_answers_at_is_refused_before_ray_is_imported(tmp_path: Path) -> None:
    """Ray's import takes most of a second; `--ray HOST:PORT` with nothing listening there is
    refused first (the extra is found installed without importing it)."""
    address = f"127.0.0.1:{free_port('127.0.0.1')}"
    args = ("eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--trials", "1", "--out", f"{tmp_path}/x")
    got, stderr = _refused(*args, "--ray", address, heavy=("ray",))
    assert got["code"] == 2, stderr
    assert f"--ray: nothing answers at {address}" in stderr, stderr
    assert got["heavy"] == [], f"the refusal imported {got['heavy']}"
    assert not (tmp_path / "x").exists()
