"""mhrc.testing, used exactly as a researcher would: the pytest plugin's fixtures (no import of
the project's own tests), a scripted robot among heuristic teammates, a scripted LLM robot
against a scripted model server, and a world with agents attached by hand."""

from __future__ import annotations

import asyncio
import itertools
import socket
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx
import pytest
from waits import until_sync

from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.llm import make_client
from mhrc.agents.llm_policy import LLMPolicy
from mhrc.core.keys import Keys
from mhrc.core.protocol import Action, EpisodeDone, Observation, OutcomeCode, SkillOutcome, Thought, decode_event
from mhrc.core.records import ReplyFailure
from mhrc.testing import ModelCall, ModelReply, PolicyHarness, ScriptedModelServer, ScriptedPolicy, observation, outcome


def test_the_plugin_is_registered(pytestconfig: pytest.Config) -> None:
    assert pytestconfig.pluginmanager.hasplugin("mhrc")
    import mhrc.testing.plugin

    assert pytestconfig.pluginmanager.get_plugin("mhrc") is mhrc.testing.plugin


def test_the_plugin_costs_nothing_to_a_session_that_uses_no_fixture() -> None:
    """pytest loads the plugin in every session of a project that installed mhrc: loading it
    (and `mhrc.testing`) imports neither Zenoh nor PyBullet nor the world; a name of the harness
    brings Zenoh and the world when it is used (PyBullet comes when an episode builds its
    simulator, mhrc.run.config.EpisodeConfig.sim)."""
    heavy = ("zenoh", "pybullet", "mhrc.world")
    probe = (
        "import sys, mhrc.testing.plugin, mhrc.testing\n"
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))\n"
        "from mhrc.testing import run_episode\n"
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.splitlines() == ["[]", str(sorted(set(heavy) - {"pybullet"}))], out.stderr


def test_a_scripted_policy_checks_its_commands_at_once() -> None:
    policy = ScriptedPolicy(["navigate(table_0, 0)", "Command: pick(apple)"])
    assert [a.call() for a in policy.actions] == ["navigate(table_0, 0)", "pick(apple)"] and policy.remaining == 2
    with pytest.raises(ValueError, match=r"scripted command 1 \('flyto\(moon\)'\)"):
        ScriptedPolicy(["wait()", "flyto(moon)"])


def test_the_model_server_answers_from_its_script_with_latency(mhrc_model_server: Any) -> None:
    server = mhrc_model_server(
        {"alice": ["Command: wait()", ModelReply(status=503, latency=0.0)]}, latency=0.2, when_done=None
    )
    ask = {"model": "m", "messages": [{"role": "system", "content": "You are Alice, a robot."}]}
    with httpx.Client() as http:
        first = http.post(f"{server.url}/chat/completions", json=ask)
        assert first.status_code == 200 and first.json()["choices"][0]["message"]["content"] == "Command: wait()"
        assert http.post(f"{server.url}/chat/completions", json=ask).status_code == 503
        assert http.post(f"{server.url}/chat/completions", json=ask).status_code == 500  # the script is exhausted
    assert server.requests == [ask] * 3 and server.paths == ["/v1/chat/completions"] * 3
    assert [call.latency for call in server.calls] == [
        0.2,
        0.0,
        0.0,
    ]  # the server's, the reply's own, none for an exhausted script
    assert ScriptedModelServer.robot_of(ask) == "alice" and len(server.requests_of("alice")) == 3


def test_model_replies_set_usage_reasoning_and_headers(mhrc_model_server: Any) -> None:
    """`usage` estimated, given or left out; reasoning under the field a server uses; headers
    that replace the server's own; `remaining()` counts what the script has not said yet."""
    server = mhrc_model_server(
        [
            "Command: wait()",
            ModelReply(
                "Command: wait()",
                usage={
                    "prompt_tokens": 9,
                    "completion_tokens": 30,
                    "completion_tokens_details": {"reasoning_tokens": 21},
                },
            ),
            ModelReply("Command: wait()", usage=False, reasoning="think", reasoning_field="reasoning"),
            ModelReply(body=b"plain", headers={"Content-Type": "text/plain", "X-Test": "1"}),
        ],
        when_done=None,
    )
    ask = {"model": "m", "messages": [{"role": "user", "content": "x" * 40}]}
    assert server.remaining() == 4
    with httpx.Client() as http:
        replies = [http.post(f"{server.url}/chat/completions", json=ask) for _ in range(4)]
    assert replies[0].json()["usage"] == {"prompt_tokens": 10, "completion_tokens": 3}
    assert replies[1].json()["usage"]["completion_tokens_details"] == {"reasoning_tokens": 21}
    third = replies[2].json()
    assert "usage" not in third and third["choices"][0]["message"]["reasoning"] == "think"
    assert "reasoning_content" not in third["choices"][0]["message"]
    assert replies[3].headers.get_list("Content-Type") == ["text/plain"] and replies[3].headers["X-Test"] == "1"
    assert replies[3].content == b"plain" and server.remaining() == 0


def test_the_model_server_records_which_calls_overlapped(mhrc_model_server: Any) -> None:
    """Each call's start and end in one count, its reply and latency; in-flight requests counted."""
    both_in = threading.Barrier(2, timeout=10.0)  # the two first calls answer once both arrived

    def script(body: dict[str, Any]) -> ModelReply:
        if body["latency"]:
            both_in.wait()
        return ModelReply("Command: wait()", latency=body["latency"])

    server = mhrc_model_server(script)
    ask = [
        {"model": "m", "messages": [{"role": "system", "content": f"You are {name}, a robot."}], "latency": 0.1}
        for name in ("Alice", "Bob")
    ]
    with ThreadPoolExecutor(2) as pool:
        assert [
            r.status_code for r in pool.map(lambda body: httpx.post(f"{server.url}/chat/completions", json=body), ask)
        ] == [200, 200]
    with httpx.Client() as http:
        http.post(f"{server.url}/chat/completions", json={**ask[0], "latency": 0.0})
    calls = server.calls
    assert all(isinstance(c, ModelCall) for c in calls) and [c.request for c in calls] == server.requests
    assert sorted(c.robot for c in calls) == ["alice", "alice", "bob"] and calls[-1].latency == 0.0
    first, second, third = sorted(calls, key=lambda c: c.started)
    assert first.ended is not None and second.ended is not None and third.ended is not None
    assert second.started < first.ended and first.started < second.ended  # the two slow calls overlapped
    assert max(first.ended, second.ended) < third.started < third.ended  # the last came after both
    assert all(c.reply is not None and c.reply.text == "Command: wait()" for c in calls)
    assert server.max_in_flight == 2 and server.in_flight == 0


def test_an_endless_stream_is_written_until_the_client_hangs_up_or_the_server_closes() -> None:
    """A body trickled chunk by chunk for ever: the client reads what it likes and leaves; closing
    the server ends every stream and latency still running."""

    def stream(body: dict[str, Any]) -> ModelReply:
        return ModelReply(stream=itertools.chain([b'{"choices": ['], itertools.repeat(b" ")), stream_interval=0.01)

    server = ScriptedModelServer(stream)
    try:
        with httpx.Client() as http, http.stream("POST", f"{server.url}/chat/completions", json={}) as resp:
            assert resp.status_code == 200 and "Content-Length" not in resp.headers
            got = b""
            for chunk in resp.iter_bytes():
                got += chunk
                if len(got) > 40:
                    break
        assert got.startswith(b'{"choices": [') and got[13:].strip() == b""
        with socket.create_connection(("127.0.0.1", server.port)) as sock:  # a client that listens on
            sock.sendall(b"POST /v1/chat/completions HTTP/1.0\r\nContent-Length: 2\r\n\r\n{}")
            assert sock.recv(12).startswith(b"HTTP/1.1 200")  # uvicorn's status line, to an HTTP/1.0 client too
            sock.settimeout(10.0)
            ender = threading.Timer(0.2, server.close)
            ender.start()
            while sock.recv(4096):  # an endless stream: only the server's close ends it (else recv times out)
                pass
            ender.join()
    finally:
        server.close()
    slow = ScriptedModelServer(["Command: wait()"], latency=30.0)
    with socket.create_connection(("127.0.0.1", slow.port)) as sock:
        sock.sendall(b"POST /v1/chat/completions HTTP/1.0\r\nContent-Length: 2\r\n\r\n{}")
        until_sync(lambda: slow.requests, "the request reached the server", every=0.01)
        slow.close()  # cuts the 30 s latency short: the answer comes before the socket's 10 s timeout
        sock.settimeout(10.0)
        assert sock.recv(12).startswith(b"HTTP/1.1 200")  # uvicorn's status line, to an HTTP/1.0 client too


def test_a_reply_can_stall_after_its_headers_or_drop_the_connection(mhrc_model_server: Any) -> None:
    """Two faults of a server gone bad: a stream that stops mid-reply and holds the connection
    open (silence, until the client's read timeout), and a connection closed without an answer."""
    server = mhrc_model_server(
        [ModelReply(stream=[b"data: first\n\n"], stall=True), ModelReply(drop=True), ModelReply(stall=True)],
        when_done=None,
    )
    with httpx.Client(timeout=httpx.Timeout(30.0, read=0.5)) as http:
        with http.stream("POST", f"{server.url}/chat/completions", json={}) as resp:
            chunks = resp.iter_raw()
            assert resp.status_code == 200 and next(chunks) == b"data: first\n\n"
            with pytest.raises(httpx.ReadTimeout):  # not the end of the body: nothing more, ever
                next(chunks)
        with pytest.raises(httpx.RemoteProtocolError, match="without sending a response"):
            http.post(f"{server.url}/chat/completions", json={})
        with http.stream("POST", f"{server.url}/chat/completions", json={}) as resp:
            assert resp.status_code == 200
            with pytest.raises(httpx.ReadTimeout):  # headers, and no body
                resp.read()
    assert len(server.requests) == 3 and server.remaining() == 0


def test_a_content_length_that_lies_is_a_body_cut_short(mhrc_model_server: Any) -> None:
    """A length longer than the body: the body, then the connection closes (a server dying
    mid-body); the client reads a truncated message, not a hang."""
    server = mhrc_model_server(
        [ModelReply(body=b'{"choices": [', headers={"Content-Length": "100"}), "Command: wait()"], when_done=None
    )
    with httpx.Client(timeout=10.0) as http:
        with pytest.raises(httpx.RemoteProtocolError, match="incomplete|closed"):
            http.post(f"{server.url}/chat/completions", json={})
        assert http.post(f"{server.url}/chat/completions", json={}).status_code == 200  # the server serves on
    assert [c.connection for c in server.calls] == [1, 2]


def test_a_keep_alive_server_answers_many_requests_on_one_connection(mhrc_model_server: Any) -> None:
    server = mhrc_model_server(["Command: wait()"] * 3, keep_alive=True)
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.settimeout(10.0)
        reader = sock.makefile("rb")
        for _ in range(3):
            sock.sendall(b"POST /v1/chat/completions HTTP/1.1\r\nHost: x\r\nContent-Length: 2\r\n\r\n{}")
            assert reader.readline().startswith(b"HTTP/1.1 200")
            headers = {}
            while (line := reader.readline()) not in (b"\r\n", b""):
                name, _, value = line.decode().partition(":")
                headers[name.lower()] = value.strip()
            assert b"Command: wait()" in reader.read(int(headers["content-length"]))
        reader.close()
    assert len(server.requests) == 3 and server.remaining() == 0


async def test_a_scripted_robot_among_heuristic_teammates(mhrc_run_episode: Any) -> None:
    """David plays a script, Alice and Bob the heuristic policy (not named: their default)."""
    script = ["navigate(table_1, 0)", "navigate(table_0, 0)"]
    david = ScriptedPolicy(script)
    result = await mhrc_run_episode({"david": david}, seed=0, n_objects=3, horizon=30)
    assert result.done.reason in ("success", "horizon") and result.metrics.success == result.done.metrics.success
    assert [r.action.call() for r in david.results[:2]] == script
    assert all(r.action.call() == "wait()" for r in david.results[2:])
    assert [r.action for r in result.results("david")][:2] == ScriptedPolicy(script).actions
    assert {t.robot for t in result.thoughts()} == {"alice", "bob", "david"}
    assert {t.policy for t in result.thoughts("david")} == {"script"}
    assert [m.kind for m in result.messages("action_result", "david")] == ["action_result"] * len(
        result.results("david")
    )
    assert result.trace.is_file() and result.metrics.temporal_steps == result.done.metrics.temporal_steps


async def test_a_scripted_llm_robot_whose_bad_reply_becomes_feedback(
    mhrc_model_server: Any, mhrc_run_episode: Any
) -> None:
    """Bob on a model (the scripted server), Alice and David heuristic: Bob's first reply holds no
    command, so he waits and is told why; his second names an object that does not exist."""
    server = mhrc_model_server(
        {"bob": ["I am thinking about the tray.", "Analysis: got it.\nCommand: pick(ghost)"]}, latency=0.05
    )
    result = await mhrc_run_episode({}, seed=0, horizon=3, llm="bob=openai:test", base_url=server.url)
    assert result.done.reason == "horizon" and result.metrics.temporal_steps == 3
    bob = result.thoughts("bob")
    assert bob[0].parse_error and "no command" in bob[0].parse_error and bob[0].action == "wait()"
    assert "Your command could not be read, so you waited." in (
        bob[1].prompt or ""
    )  # the format error came back as feedback
    assert bob[1].action == "pick(ghost)" and result.done.metrics.failed_actions.get("pick") == 1
    assert all(t.policy == "llm:test" for t in bob) and len(server.requests_of("bob")) == len(bob) == len(
        server.requests
    )
    assert {t.policy for t in result.thoughts("alice") + result.thoughts("david")} == {"heuristic"}
    failures = [line.failure for line in result.records if isinstance(line.msg, Thought) and line.msg.robot == "bob"]
    assert failures[:2] == [ReplyFailure.UNREADABLE, None]  # the code the trace's reader derived, once
    assert result.metrics.parse_failures == 1


async def test_a_world_with_agents_attached_by_hand(mhrc_world: Any) -> None:
    """Every robot waits, each on its own session; a session of our own sees the episode end."""
    async with mhrc_world(seed=0, horizon=2) as world:
        assert world.endpoint.startswith("tcp/127.0.0.1:") and world.config.horizon == 2
        events: list[EpisodeDone] = []
        bus = await world.client()
        bus.subscribe(
            Keys(world.run).world_event,
            lambda s: events.append(e) if isinstance(e := decode_event(s.payload), EpisodeDone) else None,
        )
        policies = {robot: ScriptedPolicy([]) for robot in world.config.robots}
        tasks = [await world.agent(robot, policy) for robot, policy in policies.items()]
        done = await world.done()
        seen = await asyncio.wait_for(asyncio.gather(*tasks), 30)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 2
    assert all(s is not None and s.reason == "horizon" for s in seen)
    assert all(len(p.results) == 2 and p.results[-1].done for p in policies.values())
    assert [e.reason for e in events] == ["horizon"] and world.trace.is_file()


async def test_attached_returns_once_the_robots_named_are_attached(mhrc_world: Any) -> None:
    """The world waits for all three robots: the first two stay attached meanwhile, and
    `attached` sees the world accept them; the episode starts when the third comes."""
    async with mhrc_world(seed=0, horizon=1) as world:
        with pytest.raises(ValueError, match="no such robot in this episode: zed"):
            await world.attached("zed")
        for robot in ("alice", "bob"):
            await world.agent(robot, ScriptedPolicy([]))
        await world.attached("alice", "bob")
        assert not world.world.done()  # still waiting for david
        with pytest.raises(TimeoutError):
            await world.attached("david", timeout=0.5)
        await world.agent("david", ScriptedPolicy([]))
        assert (await world.done()).reason == "horizon"


# -- the in-memory harness: a policy's unit tests, nothing started ----------------------------------


async def test_the_heuristic_bob_picks_then_places_and_asks_alice_for_what_is_missing() -> None:
    """Bob's scripted expert, fed hand-built observations: a target on his table is picked and
    put in the tray; one he cannot see he asks Alice for."""
    harness = PolicyHarness(heuristic_policy("bob"))
    assert (
        await harness.decide(observation("bob", objects={"phone": "table_0"}, targets=["phone"]))
    ).action.call() == "pick(phone)"
    harness.answer(observation=observation("bob", holding="phone", targets=["phone"], tick=1))
    assert (await harness.decide(harness.next_observation)).action.call() == "place(phone, tray)"
    harness.answer()
    assert [r.tick for r in harness.results] == [0, 1] and harness.next_observation.tick == 2

    asking = PolicyHarness(heuristic_policy("bob"))
    actions = await asking.run(observation("bob", objects={"phone": "table_2"}, targets=["phone", "book"]), 2)
    assert actions[0] == "communicate('Alice, please bring these to table_0 within my reach: phone, book.', alice)"
    assert actions[1] == "wait()" and all(r.outcome.succeeded for r in asking.results)


async def test_the_heuristic_david_explores_what_alice_hands_him_and_reports_it() -> None:
    """A message in, a navigation out; the world function answers with what he then sees."""

    def world(action: Action, obs: Observation) -> tuple[SkillOutcome, Observation | None]:
        if action.skill == "navigate":  # he arrives and sees the book on table_2
            return outcome(feedback="You arrived at table_2."), observation(
                "david", tick=obs.tick + 1, objects={"book": "table_2"}
            )
        return outcome(), None

    harness = PolicyHarness(heuristic_policy("david"))
    ask = observation(
        "david", messages=[("alice", "David, please explore these surfaces and tell me what lies on them: table_2.")]
    )
    assert await harness.run(ask, 3, world) == [
        "navigate(table_2, 0)",
        "communicate('On table_2 I found: book.', alice)",
        "wait()",
    ]
    assert harness.steps[1].observation.objects[0].on == "table_2" and harness.steps[1].result is not None


async def test_an_llm_policy_in_the_harness_reads_its_feedback_and_survives_a_reply_without_a_command(
    mhrc_model_server: Any,
) -> None:
    """The LLM robot against a scripted model, without a world: its prompt shows the hand-built
    observation, a failure's feedback reaches the next prompt, and an unreadable reply becomes
    a wait with the parse error."""
    server = mhrc_model_server({"bob": ["Analysis: the phone is close.\nCommand: pick(phone)", "I am not sure."]})
    client = make_client("openai:test", base_url=server.url)
    try:
        harness = PolicyHarness(LLMPolicy("bob", client))
        obs = observation("bob", objects={"phone": "table_0"}, targets=["phone"])
        first = await harness.step(obs, outcome("out_of_reach", "The phone is beyond your arm's reach."))
        second = await harness.decide(harness.next_observation)
    finally:
        await client.aclose()
    assert (first.action.call(), first.parse_error) == ("pick(phone)", None) and first.reply is not None
    assert second.action.call() == "wait()" and second.parse_error and "no command" in second.parse_error
    prompts = [r["messages"][-1]["content"] for r in server.requests_of("bob")]
    assert "- phone: position" in prompts[0] and "The list: phone." in prompts[0]
    assert "The phone is beyond your arm's reach." in prompts[1] and [
        ScriptedModelServer.step_of(r) for r in server.requests
    ] == [0, 1]
    assert harness.actions == ["pick(phone)", "wait()"] and harness.results[0].outcome.code is OutcomeCode.OUT_OF_REACH


def test_the_harness_builds_observations_the_protocol_accepts_and_keeps_the_loop_in_order() -> None:
    obs = observation(
        "alice",
        tick=3,
        holding="apple",
        objects={"apple": "cabinet_0"},
        messages=[("bob", "hi")],
        goals={"apple": "tray"},
    )
    assert obs.status.holding == "apple" and obs.objects[0].inside and obs.new_messages[0].sender == "bob"
    assert set(obs.teammates) == {"bob", "david"} and obs.goals == {"apple": "tray"} and obs.tick == 3
    assert Observation.model_validate_json(obs.model_dump_json()) == obs  # what the world would send
    with pytest.raises(ValueError, match="not among the observation's furniture"):
        observation("bob", objects={"phone": "moon"})
    with pytest.raises(ValueError, match="no default status for robot 'zed'"):
        observation("zed")
    assert outcome("no_path", "No path.").code is OutcomeCode.NO_PATH and outcome().succeeded
    harness = PolicyHarness(ScriptedPolicy(["wait()"]))
    with pytest.raises(RuntimeError, match="decide\\(\\) first"):
        harness.answer()
    asyncio.run(harness.decide(obs))
    with pytest.raises(RuntimeError, match="answer\\(\\) it before deciding again"):
        asyncio.run(harness.decide(obs))
