"""`HumanPolicy`: a robot's policy whose decisions a person makes on the play page.

It sees what an LLM policy sees, the robot's own `Observation` and the histories an agent keeps
of it (feedback, messages, actions: mhrc.agents.memory), rendered in the same words
(mhrc.agents.observation). `decide` shows them to the page and awaits the person's submission;
a submission that cannot be sent is refused with a code and a sentence and the person chooses
again. The decision's latency is the time the person took; its thought says policy `human`.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable

from mhrc.agents import observation as describe
from mhrc.agents.memory import HISTORIES, Memory
from mhrc.agents.policy import Decision
from mhrc.core.protocol import ActionResult, Observation
from mhrc.core.protocol.thoughts import HUMAN_POLICY

from .forms import MAX_SUBMISSION_BYTES, Refusal, Refused, action_of, as_json, forms
from .messages import HistoryEntry, PageMessage, Submission, View

POLICY = HUMAN_POLICY
Send = Callable[[PageMessage], None]  # one JSON message to the page


class HumanPolicy:
    """The person's decisions, one per observation, through `send` (to the page) and `submit` (from it)."""

    name = POLICY

    def __init__(self, robot: str) -> None:
        self.robot = robot
        self.memory = Memory()
        self.obs: Observation | None = None
        self.shown_at = 0.0  # time.monotonic() when the current observation reached the person
        self.last_submission: Submission | None = None
        self._pending: asyncio.Future[Decision] | None = None
        self._send: Send | None = None
        self.decisions = 0
        self.house: Callable[[Observation], tuple[str, str]] | None = None  # the map: (its scene, its SVG)

    # ------------------------------------------------------------------ the page
    def connect(self, send: Send | None) -> None:
        """The page that shows this robot now (None: none); it gets the current view at once."""
        self._send = send
        if send is not None and self.obs is not None:
            send(self.view())

    def _tell(self, message: PageMessage) -> None:
        if self._send is not None:
            self._send(message)

    @property
    def deciding(self) -> bool:
        return self._pending is not None and not self._pending.done()

    def view(self) -> View:
        """What the page shows: the observation (as sent and in an agent's words), the histories,
        the forms with their choices, and whether a decision is awaited."""
        obs = self.obs
        assert obs is not None
        text = {
            "status": describe.robot_status(obs),
            "task": describe.task_text(obs),
            "progress": describe.progress_text(obs),
            "scene_graph": describe.scene_graph(obs),
            "teammates": describe.teammates(obs),
        }
        scene, svg = self.house(obs) if self.house is not None else ("", "")
        histories = {n: [HistoryEntry(step=e.step, text=e.text) for e in self.memory.history(n)] for n in HISTORIES}
        return {
            "type": "view",
            "tick": obs.tick,
            "deciding": self.deciding,
            "waited": round(time.monotonic() - self.shown_at, 1),
            "observation": obs.model_dump(mode="json"),
            "text": text,
            "histories": histories,
            "forms": as_json(forms(obs)),
            "last": self.last_submission,
            "map": svg,
            "map_scene": scene,
        }

    # ------------------------------------------------------------------ the policy
    async def decide(self, obs: Observation) -> Decision:
        for m in obs.new_messages:
            self.memory.add("messages", m.tick, f"from {m.sender.capitalize()}: {m.content}", tag=f"from {m.sender}")
        self.obs = obs
        self.shown_at = time.monotonic()
        self._pending = asyncio.get_running_loop().create_future()
        self._tell(self.view())
        try:
            return await self._pending
        finally:
            self._pending = None

    def submit(self, raw: str | bytes) -> None:
        """A form's submission from the page: decided, or refused on the page with the reason."""
        try:
            submission = self._parse(raw)
            if not self.deciding or self.obs is None:
                raise Refused(Refusal.NOT_DECIDING, f"{self.robot}'s action is under way: wait for its result")
            action = action_of(submission, self.obs)
        except Refused as refused:
            self._tell({"type": "refused", "code": refused.code.value, "reason": refused.reason})
            return
        self.last_submission = {k: v for k, v in submission.items() if k not in ("type", "tick")}
        self.decisions += 1
        latency = round(time.monotonic() - self.shown_at, 3)
        self._tell({"type": "accepted", "tick": self.obs.tick, "action": action.call()})
        assert self._pending is not None
        self._pending.set_result(Decision(action=action, latency=latency))

    @staticmethod
    def _parse(raw: str | bytes) -> Submission:
        if len(raw) > MAX_SUBMISSION_BYTES:
            raise Refused(
                Refusal.MALFORMED,
                f"payload: {len(raw)} bytes, more than the {MAX_SUBMISSION_BYTES} a submission may have",
            )
        try:
            data = json.loads(raw)
        except ValueError:
            raise Refused(Refusal.MALFORMED, "the submission is not JSON") from None
        if not isinstance(data, dict):
            raise Refused(Refusal.MALFORMED, "the submission is not a JSON object")
        data.pop("type", None)
        return data

    def record(self, result: ActionResult) -> None:
        """The result of the person's last action: into the histories, and to the page."""
        call = result.action.call()
        self.memory.add("actions", result.tick, call, tag=result.action.skill)
        ok = result.outcome.succeeded
        if not (ok and result.action.skill == "wait"):
            verdict = "succeeded" if ok else "FAILED"
            self.memory.add(
                "feedback",
                result.tick,
                f"{call} {verdict}: {result.outcome.feedback}",
                tag="succeeded" if ok else "failed",
            )
        self._tell(
            {"type": "result", "tick": result.tick, "action": call, "ok": ok, "feedback": result.outcome.feedback}
        )
