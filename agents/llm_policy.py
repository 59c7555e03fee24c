"""The paper's planner: render the role's prompts from the robot's own observation and memory,
ask the model, parse exactly one command.

An unparseable reply or a model that stays down after retries never crashes the agent: the
robot waits that step, and the reason becomes feedback in its next prompt.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from string import Template

from mhrc.protocol import ActionResult, Observation, Wait

from . import observation as describe
from .llm import LLMClient, LLMError, Messages
from .memory import Memory
from .parse import ReplyFormatError, parse_command
from .policy import Decision

SIGNATURES = {
    "navigate": "navigate(furniture, stand_pose_id): drive to that stand pose of the furniture",
    "move": "move(dx, dy): shift your base by dx, dy metres (world frame), at most 1 m",
    "open": "open(furniture): open a closed drawer or door you stand at",
    "pick": "pick(object): grasp an object within reach with the suction cup",
    "place": "place(object, location): put the held object on a furniture surface or in the tray",
    "communicate": "communicate(content, robot): send a message to a teammate",
    "wait": "wait(): do nothing this step",
}


def load_template(robot: str, part: str, prompts_dir: Path | None = None) -> Template:
    """`<robot>_<part>.txt` from `prompts_dir`, else from the package's prompts."""
    name = f"{robot}_{part}.txt"
    if prompts_dir is not None:
        path = Path(prompts_dir) / name
        if not path.is_file():
            raise FileNotFoundError(f"prompt template {path} is missing (expected {name} in {prompts_dir})")
        return Template(path.read_text(encoding="utf-8"))
    return Template(resources.files("mhrc.prompts").joinpath(name).read_text(encoding="utf-8"))


class LLMPolicy:
    """One robot's LLM planner. Switches: feedback=False and history=False are the paper's ablations."""

    def __init__(
        self,
        robot: str,
        client: LLMClient,
        *,
        prompts_dir: Path | None = None,
        temperature: float = 0.5,
        feedback: bool = True,
        history: bool = True,
        prompt_cap_chars: int | None = 6000,
        teammates_absent: tuple[str, ...] = (),
    ) -> None:
        self.robot = robot
        self.client = client
        self.name = f"llm:{client.model}"
        self.temperature = temperature
        self.feedback = feedback
        self.history = history
        self.absent = teammates_absent
        self.memory = Memory(cap_chars=prompt_cap_chars)
        self.system_t = load_template(robot, "system", prompts_dir)
        self.user_t = load_template(robot, "user", prompts_dir)

    def render(self, obs: Observation) -> Messages:
        teammates = {k: v for k, v in obs.teammates.items() if k not in self.absent}
        team = "\n".join(f"- {n}: {', '.join(s)}" for n, s in teammates.items()) or "- nobody"
        absent = "".join(f"{a.capitalize()} is not part of the team in this episode.\n" for a in self.absent)
        system = self.system_t.safe_substitute(
            teammates=team, absent=absent, skills="\n".join(f"- {SIGNATURES[s]}" for s in obs.status.skills if s in SIGNATURES)
        )
        off = "(not available)"
        user = self.user_t.safe_substitute(
            scene_graph=describe.scene_graph(obs),
            status=describe.robot_status(obs),
            task=describe.task_text(obs),
            feedback=self.memory.render("feedback") if self.feedback and self.history else (self._last_feedback() if self.feedback else off),
            messages=self.memory.render("messages") if self.history else self._latest_messages(obs),
            actions=self.memory.render("actions") if self.history else off,
        )
        return [{"role": "system", "content": system}, {"role": "user", "content": user}]

    def _last_feedback(self) -> str:
        return f"- {self.memory.feedback[-1]} (latest)" if self.memory.feedback else "(none yet)"

    @staticmethod
    def _latest_messages(obs: Observation) -> str:
        return "\n".join(f"- from {m.sender}: {m.content} (latest)" for m in obs.new_messages) or "(none new)"

    async def decide(self, obs: Observation) -> Decision:
        self.memory.messages += [f"from {m.sender} at step {m.tick}: {m.content}" for m in obs.new_messages]
        messages = self.render(obs)
        prompt = "\n\n".join(m["content"] for m in messages)
        try:
            c = await self.client.complete(messages, temperature=self.temperature)
        except LLMError as exc:
            self.memory.feedback.append(f"Your planner could not reach its model ({exc}); you waited.")
            return Decision(action=Wait(), prompt=prompt, parse_error=f"llm error: {exc}")
        try:
            action = parse_command(c.text)
            error = None
        except ReplyFormatError as exc:
            action, error = Wait(), str(exc)
            self.memory.feedback.append(f"Your last reply could not be executed ({exc}); you waited instead.")
        return Decision(action, prompt, c.text, error, c.prompt_tokens, c.completion_tokens, c.latency)

    def record(self, result: ActionResult) -> None:
        self.memory.actions.append(f"step {result.tick}: {result.action.call()}")
        self.memory.feedback.append(f"step {result.tick}: {result.action.call()} -> {result.outcome.feedback}")
