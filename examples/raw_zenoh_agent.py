"""An mhrc agent written against the bus protocol alone: zenoh and json, no mhrc import.

It drives one robot of a running world (README, "Attaching your own agent"; the payloads'
JSON Schemas come from `mhrc schema`):

    python examples/raw_zenoh_agent.py --connect tcp/127.0.0.1:7447 --run demo --robot david

A secured world (`mhrc up --external david`, a tls/ endpoint) needs this robot's credentials
file, which `mhrc up` writes to runs/RUN/credentials/david.json and names in the line it prints:

    python examples/raw_zenoh_agent.py --connect tls/127.0.0.1:7447 --robot david \
        --credentials runs/RUN/credentials/david.json

The file is JSON: `run`, `user`, `password` and `ca` (the run's CA certificate, relative to the
file); the session then speaks TLS, checks the world's certificate against that CA and logs in
as `user` (zenoh's transport/link/tls and transport/auth/usrpwd settings).

1. open a zenoh session in client mode, connected to the world's endpoint, scouting off;
2. subscribe to its ack, result and turn keys and to world/event, declare the liveliness
   token alive/robot/<robot>, then `get` the attach key with an AttachRequest;
3. loop: choose an action from the observation, put an ActionRequest for the observation's
   tick, await the ack (same goal_id), then the result, whose observation is the next one;
   until a result says done or episode_done arrives.

Policy: a robot that can navigate visits the furniture in turn (first the surfaces a teammate
asked it to explore) and reports what it saw there to alice (or whoever asked) with
`communicate`; anything else it cannot do, it replaces by wait().
Exit status: 0 when the episode ended, 1 on an error (no world, rejected attach or action, timeout),
2 on bad arguments (a tls/ endpoint without credentials, a credentials file that cannot be read).
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import re
import signal
import sys
import time
import uuid
from collections.abc import Callable
from typing import Any

import zenoh

PROTOCOL_VERSION = 2
EPISODE_OVER = "the episode is over"  # an AttachReply's reason after the episode's end
OUT_OF_STEP = (
    "stale_tick",
    "tick_taken",
    "not_your_turn",
)  # ActionAck codes: the request was for a tick not (or no longer) ours
EXPLORE_RE = re.compile(
    r"explore these surfaces and tell me what lies on them:\s*([A-Za-z0-9_]+(?:\s*,\s*[A-Za-z0-9_]+)*)"
)

Json = dict[str, Any]


class Stop(Exception):
    """The episode ended (or the world left): stop playing."""


class Failure(Exception):
    """Something the agent cannot go on from."""


class Usage(Exception):
    """Arguments that cannot work (exit 2)."""


# --------------------------------------------------------------------------- the bus side


class Mailbox:
    """What the world sent this robot, filled from zenoh's threads through a queue and read by
    the main thread only (zenoh callbacks must never block)."""

    def __init__(self, robot: str) -> None:
        self.robot = robot
        self.inbox: queue.Queue[tuple[str, Json | None]] = queue.Queue()
        self.acks: dict[str, Json] = {}
        self.results: dict[str, Json] = {}
        self.turn: Json | None = None
        self.done: Json | None = None  # the episode_done event
        self.world_gone = False

    def callback(self, what: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            if what == "alive":
                if sample.kind == zenoh.SampleKind.DELETE:
                    self.inbox.put(("world_gone", None))
                return
            try:
                msg = json.loads(sample.payload.to_bytes())
            except ValueError:
                return  # not JSON: ignore
            if isinstance(msg, dict):
                self.inbox.put((what, msg))

        return on_sample

    def _take(self, what: str, msg: Json | None) -> None:
        if what == "world_gone":
            self.world_gone = True
        elif msg is None:
            return
        elif what == "ack":
            self.acks[str(msg.get("goal_id"))] = msg
        elif what == "result":
            self.results[str(msg.get("goal_id"))] = msg
        elif what == "turn" and msg.get("robot") == self.robot:
            self.turn = msg
        elif what == "event" and msg.get("kind") == "episode_done":
            self.done = msg

    def wait(self, ready: Callable[[], bool], timeout: float) -> bool:
        """Take messages until `ready()` is true (True) or `timeout` seconds passed (False)."""
        deadline = time.monotonic() + timeout
        while not ready():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            try:
                what, msg = self.inbox.get(timeout=min(left, 0.5))
            except queue.Empty:
                continue
            self._take(what, msg)
        return True


def read_credentials(path: str) -> Json:
    """A participant's credentials file (`mhrc up` writes runs/RUN/credentials/ROBOT.json), its CA made absolute."""
    try:
        with open(path, encoding="utf-8") as f:
            creds = json.load(f)
        creds["ca"] = os.path.join(os.path.dirname(os.path.abspath(path)), creds["ca"])
        return {k: creds[k] for k in ("run", "user", "password", "ca")}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise Usage(f"--credentials {path}: not a credentials file ({type(exc).__name__}: {exc})") from None


def zenoh_config(connect: str, creds: Json | None = None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/link/tx/lease", "2000")  # a hung agent is detached after 2 s, not 10
    if creds is not None:  # TLS to the world, checked against the run's CA, and a login
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(creds["ca"]))
        conf.insert_json5("transport/link/tls/verify_name_on_connect", "true")
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(creds["user"]))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(creds["password"]))
    return conf


def open_session(connect: str, timeout: float, creds: Json | None = None) -> zenoh.Session:
    """Client session to the world's endpoint, retrying while the world starts up."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return zenoh.open(zenoh_config(connect, creds))
        except zenoh.ZError:
            if time.monotonic() >= deadline:
                raise Failure(f"cannot connect to {connect} within {timeout:.0f} s") from None
            time.sleep(0.3)


# --------------------------------------------------------------------------- the agent


class Agent:
    def __init__(self, session: zenoh.Session, run: str, robot: str, step_timeout: float) -> None:
        self.session = session
        self.robot = robot
        self.base = f"mhrc/{run}/robot/{robot}"
        self.alive_key = f"mhrc/{run}/alive/robot/{robot}"
        self.agent_id = f"{robot}-raw-{uuid.uuid4().hex[:8]}"
        self.step_timeout = step_timeout
        self.box = Mailbox(robot)
        self.entities: list[Any] = []
        self.token: Any = None
        self.requests = session.declare_publisher(
            f"{self.base}/action/request", congestion_control=zenoh.CongestionControl.BLOCK
        )
        self.entities.append(self.requests)
        for key, what in (
            (f"{self.base}/action/ack", "ack"),
            (f"{self.base}/action/result", "result"),
            (f"{self.base}/turn", "turn"),
            (f"mhrc/{run}/world/event", "event"),
        ):
            self.entities.append(session.declare_subscriber(key, self.box.callback(what)))
        self.entities.append(
            session.liveliness().declare_subscriber(f"mhrc/{run}/alive/world", self.box.callback("alive"))
        )
        self.policy = ExplorerPolicy(robot)

    def close(self) -> None:
        for ent in reversed([*self.entities, *([self.token] if self.token is not None else [])]):
            try:
                ent.undeclare()
            except Exception:
                pass

    # attach ------------------------------------------------------------------
    def attach(self, timeout: float) -> Json:
        """Attach (again) and return the observation to plan on; Stop when the episode ended."""
        request = json.dumps(
            {"v": PROTOCOL_VERSION, "kind": "attach_request", "robot": self.robot, "agent_id": self.agent_id}
        )
        self.box.turn = None  # a Turn from before this attach is stale
        if self.token is None:  # before attaching: the world detaches an attached robot whose token does not come
            self.token = self.session.liveliness().declare_token(self.alive_key)
        deadline = time.monotonic() + timeout
        while True:
            reply = None
            for r in self.session.get(f"{self.base}/attach", payload=request.encode(), timeout=2.0):
                if r.ok is not None and reply is None:
                    reply = json.loads(r.ok.payload.to_bytes())
            if reply is not None:
                break
            if time.monotonic() >= deadline:
                raise Failure(f"no world answered on {self.base}/attach within {timeout:.0f} s")
            time.sleep(0.3)
        if not reply.get("accepted"):
            self.token.undeclare()  # refused: this token must not stand for a robot another agent drives
            self.token = None
            if reply.get("reason") == EPISODE_OVER:
                raise Stop("the episode is over")
            raise Failure(f"attach refused: {reply.get('reason')}")
        print(
            f"attached {self.robot} as {self.agent_id} at tick {reply['tick']} (horizon {reply['horizon']})", flush=True
        )
        if reply.get("wait_turn"):  # sequential schedule: the observation comes with a Turn
            if not self.box.wait(
                lambda: self.box.turn is not None or self.box.done is not None or self.box.world_gone, self.step_timeout
            ):
                raise Failure(f"no turn within {self.step_timeout:.0f} s")
            if self.box.turn is None:
                raise Stop("the episode ended while waiting for the turn")
            turn, self.box.turn = self.box.turn, None
            return turn["observation"]
        return reply["observation"]  # type: ignore[no-any-return]

    # one step -----------------------------------------------------------------
    def act(self, obs: Json, action: Json) -> Json | None:
        """Request `action` for the observation's tick; the result, or None when the world
        refused the tick (the caller attaches again to resynchronize)."""
        goal = uuid.uuid4().hex[:16]
        request = {
            "v": PROTOCOL_VERSION,
            "kind": "action_request",
            "goal_id": goal,
            "robot": self.robot,
            "agent_id": self.agent_id,
            "tick": obs["tick"],
            "action": action,
        }
        self.requests.put(json.dumps(request).encode())
        box = self.box
        if not box.wait(lambda: goal in box.acks or box.world_gone, 30.0):
            raise Failure(f"no ack for {goal} within 30 s")
        ack = box.acks.pop(goal, None)
        if ack is None:
            raise Stop("the world left")
        if not ack.get("accepted"):
            reason, code = str(ack.get("reason", "")), ack.get("code")
            if code == "episode_over":
                box.wait(lambda: box.done is not None, 10.0)
                raise Stop(reason)
            if code in OUT_OF_STEP:  # planned on a stale tick: attach again for the current one
                print(f"rejected ({reason}): resynchronizing", flush=True)
                return None
            raise Failure(f"the world rejected {action}: {reason}")

        # Sequential: the result comes at this robot's next turn, after the teammates acted.
        # Results and world events travel on different keys: episode_done may come first;
        # its final_results says whether this goal's result is still on its way.
        def settled() -> bool:
            if goal in box.results or box.world_gone:
                return True
            return box.done is not None and box.done.get("final_results", {}).get(self.robot) != goal

        if not box.wait(settled, self.step_timeout):
            raise Failure(f"no result for {goal} within {self.step_timeout:.0f} s")
        if (
            goal not in box.results
            and box.done is not None
            and box.done.get("final_results", {}).get(self.robot) == goal
        ):
            box.wait(lambda: goal in box.results, 10.0)
        result = box.results.pop(goal, None)
        if result is None:
            raise Stop("the episode ended before this action ran")
        return result

    def run(self, attach_timeout: float) -> None:
        obs = self.attach(attach_timeout)
        while self.box.done is None:
            action = self.policy.decide(obs)
            result = self.act(obs, action)
            if result is None:
                obs = self.attach(attach_timeout)
                continue
            outcome = result["outcome"]
            print(
                f"tick {result['tick']}: {action} -> {'ok' if outcome['succeeded'] else 'failed'}: {outcome['feedback']}",
                flush=True,
            )
            self.policy.record(action, outcome)
            obs = result["observation"]
            if result.get("done"):
                break
        self.box.wait(lambda: self.box.done is not None, 5.0)


# --------------------------------------------------------------------------- the policy


class ExplorerPolicy:
    """Visit the furniture in turn and report what lies there; wait() otherwise."""

    def __init__(self, robot: str) -> None:
        self.robot = robot
        self.priority: list[str] = []  # surfaces a teammate asked for
        self.visited: set[str] = set()
        self.pose_try: dict[str, int] = {}
        self.report_to: str | None = None
        self.last: tuple[Json, Json] | None = None

    def record(self, action: Json, outcome: Json) -> None:
        self.last = (action, outcome)

    def decide(self, obs: Json) -> Json:
        skills = set(obs["status"]["skills"])
        teammates = obs.get("teammates", {})
        for m in obs.get("new_messages", []):
            hit = EXPLORE_RE.search(m["content"])
            if hit is not None:
                self.report_to = m["sender"]
                self.priority += [n.strip() for n in hit.group(1).split(",") if n.strip() not in self.priority]
        if self.report_to is None and "alice" in teammates:
            self.report_to = "alice"
        furniture = {f["name"]: f for f in obs["furniture"]}
        if self.last is not None and self.last[0]["skill"] == "navigate":
            (action, outcome), self.last = self.last, None
            target = action["target"]
            if outcome["succeeded"]:
                self.visited.add(target)
                if "communicate" in skills and self.report_to is not None:
                    found = sorted(o["name"] for o in obs["objects"] if o.get("on") == target)
                    text = f"On {target} I found: {', '.join(found)}." if found else f"On {target} I found nothing."
                    return {"skill": "communicate", "to": self.report_to, "content": text}
            else:  # try its next stand pose, then give it up
                self.pose_try[target] = self.pose_try.get(target, 0) + 1
                if self.pose_try[target] >= len(furniture.get(target, {}).get("stand_poses", [])):
                    self.visited.add(target)
        if "navigate" in skills:
            order = [n for n in self.priority if n in furniture] + [n for n in furniture if n not in self.priority]
            for name in order:
                if name not in self.visited and furniture[name].get("stand_poses"):
                    return {"skill": "navigate", "target": name, "stand_pose": self.pose_try.get(name, 0)}
        return {"skill": "wait"}


# --------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--connect", required=True, help="the world's endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--run", default=None, help="the world's run id (default: the credentials' run)")
    ap.add_argument("--robot", required=True, help="alice, bob or david")
    ap.add_argument(
        "--credentials",
        default=os.environ.get("MHRC_CREDENTIALS"),
        help="this robot's credentials file, for a secured world (tls/ endpoint): runs/RUN/credentials/ROBOT.json; "
        "default $MHRC_CREDENTIALS",
    )
    ap.add_argument("--attach-timeout", type=float, default=30.0, help="seconds to wait for the world")
    ap.add_argument("--step-timeout", type=float, default=300.0, help="seconds to wait for a turn or a result")
    args = ap.parse_args(argv)

    def on_term(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    try:
        creds = None if args.credentials is None else read_credentials(args.credentials)
        if creds is None and args.connect.startswith("tls/"):
            raise Usage(f"--credentials: {args.connect} is a secured world; pass this robot's credentials file")
        run = args.run or (creds or {}).get("run")
        if run is None:
            raise Usage("--run: the world's run id is needed (or --credentials, which names it)")
    except Usage as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 2
    print(f"waiting for the world at {args.connect} (up to {args.attach_timeout:g} s)", file=sys.stderr, flush=True)
    try:
        session = open_session(args.connect, args.attach_timeout, creds)
    except Failure as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        return 130
    agent = None
    try:
        agent = Agent(session, run, args.robot, args.step_timeout)
        try:
            agent.run(args.attach_timeout)
        except Stop as exc:
            print(f"stopped: {exc}", flush=True)
        done = agent.box.done
        if done is not None:
            m = done["metrics"]
            print(
                f"episode_done reason={done['reason']} success={m['success']} TS={m['temporal_steps']} AS={m['action_steps']}",
                flush=True,
            )
        return 0
    except Failure as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        return 130
    finally:
        if agent is not None:
            agent.close()
        session.close()


if __name__ == "__main__":
    sys.exit(main())
