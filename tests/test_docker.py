"""docker/ and deploy/: the compose files' commands are real `mhrc` (and `ray start`) command
lines, the Ray cluster of compose.eval.yaml and of the KubeRay manifest is wired as documented
(token authentication on), the Dockerfile is sound, and the compose episode's exact commands,
run as local processes on loopback, finish an episode.

No Docker engine is needed: the compose files are read with PyYAML and interpolated here with
Compose's own rules (`${VAR}`, `${VAR:-default}`, `${VAR-default}`, `${VAR:+alt}`, `${VAR+alt}`,
`${VAR:?err}`, `$VAR`, `$$`, nested), and a string `command` is split like a shell would.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import click
import pytest
import yaml
from waits import until_sync

from mhrc.cli import main
from mhrc.core.endpoints import free_port

ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"
COMPOSE = DOCKER / "compose.yaml"
COMPOSE_EVAL = DOCKER / "compose.eval.yaml"
RAYCLUSTER = ROOT / "deploy" / "raycluster.yaml"
ROBOT_SERVICES = ("alice", "bob", "david")

# every setting the compose files read, set to a non-default value: exercises each ${VAR:+...}
FULL_ENV = {
    "MHRC_TASK": "sort_solids",
    "MHRC_SCENE": "bedroom",
    "MHRC_SEED": "7",
    "MHRC_OBJECTS": "5",
    "MHRC_HORIZON": "30",
    "MHRC_SCHEDULE": "async",
    "MHRC_ABLATION": "no_history",
    "MHRC_RUN": "docker-run",
    "MHRC_AIDS": "goal_map,status_hints",
    "MHRC_LLM": "llamacpp:local",
    "MHRC_BASE_URL": "http://llm:8080/v1",
    "MHRC_LOG_LEVEL": "info",
    "MHRC_TASKS": "pack_objects,make_sandwich",
    "MHRC_SCENES": "kitchen",
    "MHRC_TRIALS": "2",
    "MHRC_REPEATS": "3",
    "MHRC_EVAL_NAME": "gemma",
    "MHRC_WORKERS": "4",
    "MHRC_WORKER_CPUS": "8",
    "MHRC_CONCURRENCY": "3",
    "OPENAI_API_KEY": "sk-test",
}


# --- Compose interpolation -------------------------------------------------------------------

_NAME = re.compile(r"[_a-zA-Z][_a-zA-Z0-9]*")


def interpolate(text: str, env: dict[str, str]) -> str:
    """Compose's variable substitution of one string."""
    out: list[str] = []
    i = 0
    while i < len(text):
        c = text[i]
        if c != "$":
            out.append(c)
            i += 1
            continue
        nxt = text[i + 1 : i + 2]
        if nxt == "$":
            out.append("$")
            i += 2
        elif nxt == "{":
            depth, j = 1, i + 2  # find the matching }, counting nested ${
            while depth:
                if j >= len(text):
                    raise ValueError(f"unclosed ${{ in {text!r}")
                if text[j] == "}":
                    depth -= 1
                elif text[j] == "{" and text[j - 1] == "$":
                    depth += 1
                j += 1
            out.append(_braced(text[i + 2 : j - 1], env))
            i = j
        elif m := _NAME.match(text, i + 1):
            out.append(env.get(m.group(), ""))
            i = m.end()
        else:
            out.append("$")
            i += 1
    return "".join(out)


def _braced(expr: str, env: dict[str, str]) -> str:
    m = _NAME.match(expr)
    if m is None:
        raise ValueError(f"bad substitution ${{{expr}}}")
    name, rest = m.group(), expr[m.end() :]
    value = env.get(name)
    if not rest:
        return value or ""
    for op in (":-", "-", ":+", "+", ":?", "?"):
        if rest.startswith(op):
            arg = rest[len(op) :]
            present = bool(value) if op.startswith(":") else value is not None
            if op.endswith("-"):
                return value if present else interpolate(arg, env)  # type: ignore[return-value]
            if op.endswith("+"):
                return interpolate(arg, env) if present else ""
            if not present:
                raise ValueError(f"{name}: {interpolate(arg, env)}")
            return value  # type: ignore[return-value]
    raise ValueError(f"bad substitution ${{{expr}}}")


def test_interpolation_follows_compose_rules() -> None:
    env = {"A": "a", "E": ""}
    assert interpolate("${A:-x} ${E:-x} ${E-x} ${U-x} ${U:-${A}}", env) == "a x  x a"
    assert interpolate("${A:+--o ${A}} ${E:+y}|${E+y}|${U+y}|$A|$$A|${U}", env) == "--o a |y||a|$A|"
    with pytest.raises(ValueError):
        interpolate("${U:?needed}", env)


def load(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text(encoding="utf-8"))


def mhrc_services(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The services that run the mhrc image (entrypoint `mhrc`)."""
    return {n: s for n, s in doc["services"].items() if "mhrc" in interpolate(str(s.get("image", "")), {})}


def argv_of(service: dict[str, Any], env: dict[str, str]) -> list[str]:
    """The service's command with `env` substituted, as the container's arguments (after `mhrc`)."""
    cmd = service["command"]
    if isinstance(cmd, str):
        return shlex.split(interpolate(cmd, env))
    return [interpolate(str(a), env) for a in cmd]


def service_env(service: dict[str, Any], env: dict[str, str]) -> dict[str, str]:
    """The variables Compose sets in the container from the service's `environment`."""
    spec = service.get("environment") or {}
    items = spec.items() if isinstance(spec, dict) else (e.partition("=")[::2] if "=" in e else (e, None) for e in spec)
    out: dict[str, str] = {}
    for k, v in items:
        if v is None:
            if k in env:  # a bare name passes the caller's value through, if set
                out[k] = env[k]
        else:
            out[k] = interpolate(str(v), env)
    return out


def parse(argv: list[str]) -> click.Context:
    """Parse `mhrc ARGV` as click would, strictly; returns the subcommand's context."""
    assert argv and argv[0] in main.list_commands(click.Context(main)), f"not an mhrc command: {argv}"
    ctx = main.make_context("mhrc", list(argv), resilient_parsing=False)
    sub = main.get_command(ctx, argv[0])
    assert sub is not None
    return sub.make_context(argv[0], list(argv[1:]), parent=ctx, resilient_parsing=False)


def option(argv: list[str], name: str) -> str:
    return argv[argv.index(name) + 1]


# --- The compose files -----------------------------------------------------------------------


@pytest.mark.parametrize("env", [{}, FULL_ENV], ids=["defaults", "every-variable"])
@pytest.mark.parametrize("path", [COMPOSE], ids=lambda p: p.name)
def test_every_command_is_an_mhrc_command_line(path: Path, env: dict[str, str]) -> None:
    services = mhrc_services(load(path))
    assert services
    for name, service in services.items():
        argv = argv_of(service, env)
        ctx = parse(argv)
        assert ctx.command.name == argv[0], name
        joined = " ".join(argv)
        assert "${" not in joined and "$" not in joined.replace("$$", ""), f"{name}: uninterpolated {joined}"


def test_episode_compose_wiring() -> None:
    doc = load(COMPOSE)
    services = doc["services"]
    assert {"world", *ROBOT_SERVICES} <= set(services)
    world = argv_of(services["world"], {})
    ctx = parse(world)
    assert ctx.params["host"] == "0.0.0.0"  # reachable from the agents' containers
    port = ctx.params["port"]
    assert ctx.params["task"] == "pack_objects" and ctx.params["seed"] == 0
    # secured: a one-shot service issues the run's credentials, each participant mounts only its own
    issue = parse(argv_of(services["credentials"], {})).params
    assert issue["split"] and "world" in issue["hosts"] and issue["out"] == Path("/credentials")
    assert parse(argv_of(services["credentials"], FULL_ENV)).params["run"] == "docker-run"
    assert not ctx.params["insecure"] and ctx.params["credentials"] == Path("/credentials/world.json")
    assert _subpath(services["world"]) == "world"
    for robot in ROBOT_SERVICES:
        argv = argv_of(services[robot], {})
        params = parse(argv).params
        assert params["robots"] == (robot,)
        assert params["connect"] == f"tls/world:{port}"
        assert params["llm"] is None and params["run"] is None  # defaults: heuristic, the credentials' run
        assert not params["insecure"] and params["credential_files"] == (Path(f"/credentials/{robot}.json"),)
        assert _subpath(services[robot]) == robot  # never another robot's password
        assert services[robot]["depends_on"]["credentials"]["condition"] == "service_completed_successfully"
        full = parse(argv_of(services[robot], FULL_ENV)).params
        assert (full["llm"], full["base_url"], full["run"]) == ("llamacpp:local", "http://llm:8080/v1", "docker-run")
        assert service_env(services[robot], FULL_ENV)["OPENAI_API_KEY"] == "sk-test"
        assert "OPENAI_API_KEY" not in service_env(services[robot], {})
        dep = services[robot]["depends_on"]
        assert dep["world"]["condition"] == "service_healthy"
        assert dep["llm"]["required"] is False  # the llm profile is optional
    full_world = parse(argv_of(services["world"], FULL_ENV)).params
    assert (full_world["task"], full_world["seed"], full_world["run"]) == ("sort_solids", 7, "docker-run")
    # the optional llama.cpp server: its own profile, a pinned image, the GGUF mounted read-only
    llm = services["llm"]
    assert llm["profiles"] == ["llm"]
    image = interpolate(llm["image"], {})
    assert image.startswith("ghcr.io/ggml-org/llama.cpp:server-b") and not image.endswith(":latest")
    assert any(str(v).endswith(":/models:ro") for v in llm["volumes"])
    assert "--port 8080" in interpolate(llm["command"], {}) and "llm:8080" in FULL_ENV["MHRC_BASE_URL"]


def _subpath(service: dict[str, Any]) -> str | None:
    """The subdirectory of the `credentials` volume a service mounts (read-only) at /credentials."""
    for v in service.get("volumes", []):
        if isinstance(v, dict) and v.get("source") == "credentials":
            assert v["target"] == "/credentials" and v.get("read_only") is True
            return str(v["volume"]["subpath"])
    return None


def _eval_argv(head: dict[str, Any], env: dict[str, str]) -> tuple[list[str], list[str]]:
    """The head's shell command split at `&& exec mhrc`: (`ray start ...`, the mhrc arguments)."""
    (script,) = head["command"]
    ray_start, sep, rest = interpolate(script, env).partition("&& exec mhrc ")
    assert sep, script
    return shlex.split(ray_start), shlex.split(rest)


@pytest.mark.parametrize("env", [{}, FULL_ENV], ids=["defaults", "every-variable"])
def test_eval_compose_is_a_ray_head_running_mhrc_eval_and_ray_workers(env: dict[str, str]) -> None:
    doc = load(COMPOSE_EVAL)
    services = doc["services"]
    assert set(services) == {"ray-token", "head", "worker"}
    for name, service in services.items():  # one image, built with the ray extra
        assert interpolate(service["image"], env) == "mhrc:ray" and service["build"]["args"]["EXTRAS"] == "ray", name
        assert service["build"]["dockerfile"] == "docker/Dockerfile"
        senv = service_env(service, env)
        assert senv["RAY_AUTH_MODE"] == "token" and senv["RAY_AUTH_TOKEN_PATH"] == "/credentials/ray_auth_token", (
            name
        )  # Ray's token auth, on
        token = next(v for v in service["volumes"] if isinstance(v, dict) and v["source"] == "ray-token")
        assert token["target"] == "/credentials" and token.get("read_only", False) is (name != "ray-token"), name
        assert ("OPENAI_API_KEY" in senv) is ("OPENAI_API_KEY" in env)
    # the one-shot token service writes a random token once, private to its owner
    code = services["ray-token"]["command"][0]
    assert (
        services["ray-token"]["entrypoint"] == ["python", "-c"] and "secrets.token_hex(32)" in code and "0o600" in code
    )
    compile(code, "ray-token", "exec")
    assert services["head"]["depends_on"]["ray-token"]["condition"] == "service_completed_successfully"
    # the head: `ray start --head`, then the driver, `mhrc eval --ray auto`
    head = services["head"]
    assert head["entrypoint"] == ["/bin/sh", "-c"]
    ray_start, argv = _eval_argv(head, env)
    assert ray_start[:3] == ["ray", "start", "--head"] and "--port=6379" in ray_start and "--num-cpus=0" in ray_start
    params = parse(argv).params
    assert (
        argv[0] == "eval" and params["ray_address"] == "auto" and params["workers"] is None and params["resume"] is True
    )
    assert str(params["out"]) == "/data/results/" + env.get("MHRC_EVAL_NAME", "eval")
    assert "results:/data/results" in head["volumes"] and head["ports"] == [
        "127.0.0.1:8265:8265"
    ]  # the dashboard, on loopback
    assert "6379" in " ".join(head["healthcheck"]["test"])
    if env:
        assert (params["llm"], params["base_url"], params["concurrency"], params["repeats"]) == (
            "llamacpp:local",
            "http://llm:8080/v1",
            3,
            3,
        )
    else:
        assert params["llm"] is None and params["concurrency"] is None
    # the workers: `ray start --address=head:6379 --block`, N replicas, after the head is healthy
    worker = services["worker"]
    wargv = shlex.split(interpolate(worker["command"], env))
    assert worker["entrypoint"] == ["ray"] and wargv[:2] == ["start", "--address=head:6379"] and "--block" in wargv
    assert f"--num-cpus={env.get('MHRC_WORKER_CPUS', '2')}" in wargv
    assert interpolate(str(worker["deploy"]["replicas"]), env) == env.get("MHRC_WORKERS", "2")
    assert worker["depends_on"]["head"]["condition"] == "service_healthy"
    assert set(doc["volumes"]) == {"results", "ray-token"}


def test_kuberay_raycluster_runs_the_mhrc_image_with_token_auth() -> None:
    docs = [d for d in yaml.safe_load_all(RAYCLUSTER.read_text(encoding="utf-8")) if d]
    (rc,) = docs
    assert (rc["apiVersion"], rc["kind"]) == ("ray.io/v1", "RayCluster")
    import ray

    assert rc["spec"]["rayVersion"].split(".")[:2] == ray.__version__.split(".")[:2]  # the version the image installs
    head = rc["spec"]["headGroupSpec"]
    assert head["rayStartParams"]["num-cpus"] == "0"  # the head runs the driver, not episodes
    groups = rc["spec"]["workerGroupSpecs"]
    assert groups and all(
        int(g["rayStartParams"]["num-cpus"]) >= 1 and g["minReplicas"] <= g["replicas"] <= g["maxReplicas"]
        for g in groups
    )
    pods = [head["template"]["spec"], *(g["template"]["spec"] for g in groups)]
    for pod in pods:
        (c,) = pod["containers"]
        assert c["image"].endswith(":ray")  # built with --build-arg EXTRAS=ray
        env = {e["name"]: e for e in c["env"]}
        assert env["RAY_AUTH_MODE"]["value"] == "token"
        assert env["RAY_AUTH_TOKEN"]["valueFrom"]["secretKeyRef"] == {"name": "mhrc-ray-token", "key": "token"}
        assert pod["securityContext"]["runAsUser"] == 10001  # the image's user
        assert any(m["mountPath"] == "/dev/shm" for m in c["volumeMounts"])
    ports = {p["name"]: p["containerPort"] for p in head["template"]["spec"]["containers"][0]["ports"]}
    assert ports == {"gcs": 6379, "dashboard": 8265, "client": 10001}
    assert any(m["mountPath"] == "/data/results" for m in head["template"]["spec"]["containers"][0]["volumeMounts"])
    # the documented driver command is a real mhrc command line
    line = next(x for x in RAYCLUSTER.read_text(encoding="utf-8").splitlines() if "mhrc eval --ray" in x)
    params = parse(shlex.split(line.split("mhrc ", 1)[1])).params
    assert params["ray_address"] == "auto" and params["resume"] is True
    assert "kubectl create secret generic mhrc-ray-token" in RAYCLUSTER.read_text(encoding="utf-8")


# --- The Dockerfile --------------------------------------------------------------------------


def instructions(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of a Dockerfile, continuation lines joined, comments dropped."""
    out: list[tuple[str, str]] = []
    pending = ""
    for raw in path.read_text(encoding="utf-8").splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        pending += line
        if pending.endswith("\\"):
            pending = pending[:-1] + " "
            continue
        word, _, rest = pending.partition(" ")
        out.append((word.upper(), rest.strip()))
        pending = ""
    assert not pending, "a continuation line ends the Dockerfile"
    return out


def test_dockerfile_is_pinned_non_root_with_mhrc_entrypoint() -> None:
    ins = instructions(DOCKER / "Dockerfile")
    known = {
        "FROM",
        "ARG",
        "ENV",
        "WORKDIR",
        "COPY",
        "RUN",
        "USER",
        "ENTRYPOINT",
        "CMD",
        "LABEL",
        "EXPOSE",
        "VOLUME",
        "HEALTHCHECK",
    }
    assert {w for w, _ in ins} <= known
    assert ins[0][0] in ("FROM", "ARG")
    froms = [a.split()[0] for w, a in ins if w == "FROM"]
    assert froms
    for image in froms:  # an exact version tag or a digest, never a floating one
        assert re.search(r"@sha256:[0-9a-f]{64}$", image) or re.fullmatch(r"python:3\.11\.\d+-slim(-\w+)?", image), (
            image
        )
    users = [a for w, a in ins if w == "USER"]
    assert users and users[-1].split(":")[0] not in ("root", "0")
    entry = [a for w, a in ins if w == "ENTRYPOINT"]
    assert entry and json.loads(entry[-1]) == ["mhrc"]
    runs = " ".join(a for w, a in ins if w == "RUN")
    assert "pip install --no-cache-dir" in runs and "-e " not in runs and "[test" not in runs
    assert "rm -rf /var/lib/apt/lists" in runs  # no apt lists left behind
    ignore = (ROOT / ".dockerignore").read_text(encoding="utf-8").split()
    assert {"runs/", ".git/", "bench/"} <= set(ignore)
    # the build context holds what pyproject installs
    sources = {src.rstrip("/") for w, a in ins if w == "COPY" and "--from" not in a for src in a.split()[:-1]}
    # ... the package, and every top-level folder it links to (mhrc/world -> ../world): a link whose
    # target is not in the context would leave a dangling link and a package without its world
    linked = {os.readlink(p).removeprefix("../") for p in (ROOT / "mhrc").iterdir() if p.is_symlink()}
    assert linked == {"world", "agents", "prompts"}
    assert {"mhrc", "pyproject.toml", "README.md"} | linked <= sources
    assert {f"!{name}/" for name in {"mhrc"} | linked} <= set(ignore)


# --- The compose episode, run as local processes ---------------------------------------------


def _to_loopback(argv: list[str], port: int) -> list[str]:
    """Replace only the service hostnames and ports of endpoints: every address on 127.0.0.1:`port`."""
    argv = list(argv)
    for i, a in enumerate(argv[:-1]):
        if a == "--host":
            argv[i + 1] = "127.0.0.1"
        elif a == "--port":
            argv[i + 1] = str(port)
        elif a in ("--connect", "--listen"):
            argv[i + 1] = re.sub(r"^(tcp|tls)/[^:]+:\d+$", rf"\1/127.0.0.1:{port}", argv[i + 1])
    return argv


def _mhrc() -> list[str]:
    # this interpreter's own script, never an `mhrc` of another Python found on PATH
    exe = Path(sys.executable).parent / "mhrc"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "mhrc"]


def _in_groups(pgids: set[int]) -> list[str]:
    """Processes (pid and command) still alive in any of these process groups."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        fields = text.rsplit(")", 1)[1].split()
        if fields[0] != "Z" and int(fields[2]) in pgids:
            found.append(f"{stat.parent.name}: {text.split(')')[0]})")
    return found


class Processes:
    """Compose services started as local processes, each in a session (process group) of its
    own; on exit every group is killed, and nothing of them may be left."""

    def __init__(self, cwd: Path) -> None:
        self.cwd = cwd
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._logs: list[Any] = []

    def start(
        self, name: str, service: dict[str, Any], env: dict[str, str], port: int, rewrite: dict[str, str] | None = None
    ) -> None:
        argv = _to_loopback(argv_of(service, env), port)
        for old, new in (rewrite or {}).items():
            argv = [a.replace(old, new) for a in argv]
        log = open(self.cwd / f"{name}.log", "wb")  # noqa: SIM115
        self._logs.append(log)
        self.procs[name] = subprocess.Popen(
            _mhrc() + argv,
            cwd=self.cwd,
            env={**env, **service_env(service, env)},
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )

    def out(self, name: str) -> str:
        return (self.cwd / f"{name}.log").read_text(errors="replace")[-3000:]

    def wait(self, name: str, timeout: float) -> int:
        """The exit code of `name` (its output and everyone's in the message if it does not end)."""
        try:
            return self.procs[name].wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(
                f"{name} did not end within {timeout:.0f} s\n"
                + "\n".join(f"--- {n}\n{self.out(n)}" for n in self.procs)
            )

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        pgids = {p.pid for p in self.procs.values()}
        for pgid in pgids:  # the process and whatever it left in its group
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for p in self.procs.values():
            p.wait(timeout=30)
        for f in self._logs:
            f.close()
        until_sync(lambda: not _in_groups(pgids), f"no stray process in the groups {sorted(pgids)}", 10, every=0.2)


def _compose_env(**settings: str) -> dict[str, str]:
    """This environment without any MHRC_ setting (so the compose defaults apply), plus `settings`."""
    return {**{k: v for k, v in os.environ.items() if not k.startswith("MHRC_")}, **settings}


@pytest.mark.slow
def test_compose_episode_runs_as_local_processes(tmp_path: Path) -> None:
    services = load(COMPOSE)["services"]
    env = _compose_env()
    port = free_port("127.0.0.1")
    creds = tmp_path / "credentials"  # the volume; a service's subpath mount is its subdirectory
    with Processes(tmp_path) as ps:
        ps.start("credentials", services["credentials"], env, port, rewrite={"/credentials": str(creds)})
        assert ps.wait("credentials", 60) == 0, ps.out("credentials")
        for name in ("world", *ROBOT_SERVICES):
            ps.start(
                name, services[name], env, port, rewrite={"/credentials": str(creds / str(_subpath(services[name])))}
            )
        code = ps.wait("world", 240)
        assert code == 0, f"world: {code}\n{ps.out('world')}\n" + "\n".join(map(ps.out, ROBOT_SERVICES))
        for name in ROBOT_SERVICES:
            assert ps.wait(name, 30) == 0, f"{name}:\n{ps.out(name)}"
            assert "episode" in ps.out(name) and "ended" in ps.out(name)
    traces = list((tmp_path / "runs").glob("*/trace.jsonl"))
    assert len(traces) == 1, traces
    msgs = [e.get("msg") for e in map(json.loads, traces[0].read_text().splitlines())]
    kinds = [m["kind"] for m in msgs if isinstance(m, dict) and "kind" in m]
    assert kinds.count("episode_started") == 1 and kinds.count("episode_done") == 1
    done = next(m for m in msgs if isinstance(m, dict) and m.get("kind") == "episode_done")
    assert set(done["metrics"]["action_steps_per_robot"]) == set(ROBOT_SERVICES)
    assert "tls/127.0.0.1" in ps.out("world") and "insecure" not in ps.out("world")  # the secured bus


def test_documented_up_commands_survive_the_one_shot_services() -> None:
    """`--exit-code-from` implies `--abort-on-container-exit`: the `credentials` service's exit
    (or a worker's, an agent's a moment before the world's) would stop the whole stack. Every
    documented `up` that names a service's exit code also passes `--abort-on-container-failure`."""
    lines = [
        line
        for path in (DOCKER / "README.md", COMPOSE, COMPOSE_EVAL)
        for line in path.read_text(encoding="utf-8").splitlines()
        if "docker compose" in line and " up" in line
    ]
    assert lines
    for line in lines:
        if "--exit-code-from" in line:
            assert "--abort-on-container-failure" in line, line
    assert any("--exit-code-from world" in line for line in lines) and any(
        "--exit-code-from head" in line for line in lines
    )
