"""How fetchers split the work without doing it twice (heuristic.py states the protocol): what a
fetcher claims, hears claimed, hands on and reports, all over `communicate` messages.

A fetcher about to fetch an object, or to explore a container (or, in a team without scouts, a
surface), that it has not claimed yet, first tells every other attached fetcher, one message a
step: "Carol, I am fetching apple." / "Carol, I am exploring fridge.". A fetcher skips what an
attached teammate claimed. Two claims of one thing that cross (sent before either was heard):
the fetcher whose name sorts first keeps it, the other lets it go (each decides alone, the same
way). A claim lapses when its fetcher is no longer attached, and an object's when the finisher
asks for it again. A fetcher that does not lead reports each place it claimed and explored to
the lead, in a scout's words ("On fridge I found: apple, milk."), with its claim of what it
will fetch from there in the same message ("... I am fetching apple."), so the lead knows the
place is done. The lead hands an object it knows the place of and will not fetch next to
another fetcher ("Carol, I leave these to you to fetch: apple."; the message also tells Carol
where it lies): one it knows beside the one it fetches or holds, in turn to each working
fetcher; the fetcher handed them claims them to the other fetchers ("Frank, I am fetching
these: apple."), so that nobody fetches again what it has brought to table_0. Alone (the paper's team) a fetcher claims and reports nothing."""

from __future__ import annotations

from dataclasses import dataclass, field

from mhrc.core.protocol import Communicate, ObjectView, Observation

from .heuristic_base import (
    CLAIM_RE,
    EXPLORING_RE,
    HANDOFF_RE,
    _dist2,
    _names,
    _RoleBase,
    claim_sentence,
    exploring_sentence,
    handoff_sentence,
    report_sentence,
)
from .policy import Decision


@dataclass
class Claims(_RoleBase):
    """A fetcher's claims, and those it heard: what is whose."""

    needed: list[str] = field(default_factory=list)
    explored: set[str] = field(default_factory=set)
    objects: dict[str, str] = field(default_factory=dict)  # object -> the fetcher that fetches it
    places: dict[str, str] = field(default_factory=dict)  # container or surface -> the fetcher that explores it
    just_explored: str | None = None  # a place this fetcher claimed and has just seen: to report to the lead
    handoffs: int = 0

    # ---- who
    def _fetchers(self, obs: Observation) -> list[str]:
        """The other attached fetchers, in name order."""
        return self._with_role(obs, "fetcher")

    def _lead(self, obs: Observation) -> bool:
        """Whether this robot leads the fetchers: the first by name of those attached."""
        return all(obs.robot < other for other in self._fetchers(obs))

    def _taken(self, obs: Observation, obj: str) -> bool:
        owner = self.objects.get(obj)
        return owner is not None and owner != obs.robot and owner in obs.teammates

    def _place_taken(self, obs: Observation, place: str) -> bool:
        owner = self.places.get(place)
        return owner is not None and owner != obs.robot and owner in obs.teammates

    def _others_exploring(self, obs: Observation) -> bool:
        """Another attached fetcher claimed a place it has not reported on yet."""
        return any(self._place_taken(obs, p) and p not in self.explored for p in self.places)

    # ---- hearing
    def _read_claims(self, obs: Observation) -> None:
        for m in obs.new_messages:
            for hit in CLAIM_RE.finditer(m.content):
                for name in _names(hit.group(1)):
                    self._heard(obs, self.objects, name, m.sender)
            for hit in EXPLORING_RE.finditer(m.content):
                self._heard(obs, self.places, hit.group(1), m.sender)
            for hit in HANDOFF_RE.finditer(m.content):
                given = _names(hit.group(1))
                for name in given:
                    self.objects[name] = obs.robot
                    if name not in self.needed:
                        self.needed.append(name)
                # the other fetchers hear the claim too: else one of them, seeing it lie on table_0
                # once this one has brought it, fetches it again
                others = [f for f in self._fetchers(obs) if f != m.sender]
                self.outbox.extend(Communicate(to=o, content=claim_sentence(given, o)) for o in others)

    @staticmethod
    def _heard(obs: Observation, table: dict[str, str], item: str, sender: str) -> None:
        """`sender` claims `item`: it is the sender's unless an attached fetcher whose name sorts
        first (this robot among them) claimed it too."""
        owner = table.get(item)
        if owner is None or owner == sender or (owner != obs.robot and owner not in obs.teammates):
            table[item] = sender
        else:
            table[item] = min(owner, sender)

    # ---- claiming
    def _claim(self, obs: Observation, obj: ObjectView) -> Decision | None:
        """Claim `obj` before fetching it, if other fetchers are attached and it is not mine yet,
        with every other object to fetch on the same furniture (two fetchers at one piece of
        furniture get in each other's way)."""
        others = self._fetchers(obs)
        if not others or self.objects.get(obj.name) == obs.robot:
            return None
        group = self._same_place(obs, obj)
        for o in group:
            self.objects[o] = obs.robot
        return self._send(obs, [Communicate(to=o, content=claim_sentence(group, o)) for o in others])

    def _same_place(self, obs: Observation, obj: ObjectView) -> list[str]:
        """`obj` and the other objects to fetch this robot knows on the same furniture."""
        return [obj.name] + sorted(
            o.name for o in obs.objects if o.name != obj.name and o.on == obj.on and self._fetchable(obs, o)
        )

    def _claim_place(self, obs: Observation, place: str) -> Decision | None:
        """Claim `place` before exploring it, if other fetchers are attached and it is not mine yet."""
        others = self._fetchers(obs)
        if not others or self.places.get(place) == obs.robot:
            return None
        self.places[place] = obs.robot
        return self._send(obs, [Communicate(to=o, content=exploring_sentence(place, o)) for o in others])

    def _saw(self, place: str) -> None:
        """This fetcher has just seen inside or on `place` (to report, if it claimed it)."""
        self.explored.add(place)
        self.just_explored = place

    def _report_explored(self, obs: Observation) -> Decision | None:
        """Not leading: tell the lead what lies in the place just explored, and claim the needed
        object there nearest to this robot in the same message (the other fetchers hear the claim
        in messages of their own)."""
        place, self.just_explored = self.just_explored, None
        others = self._fetchers(obs)
        if place is None or not others or self.places.get(place) != obs.robot:
            return None
        lead = others[0]
        found = sorted(o.name for o in obs.objects if o.on == place)
        text = report_sentence(place, found)
        wanted = sorted(o.name for o in obs.objects if o.name in found and self._fetchable(obs, o))
        if wanted:
            for name in wanted:
                self.objects[name] = obs.robot
            text += " " + claim_sentence(wanted)
            rest = [Communicate(to=o, content=claim_sentence(wanted, o)) for o in others[1:]]
            return self._send(obs, [Communicate(to=lead, content=text), *rest])
        return self._send(obs, [Communicate(to=lead, content=text)])

    # ---- handing on (the lead)
    def _handoff(self, obs: Observation) -> Decision | None:
        """Hand the known objects on one piece of furniture to another working fetcher when this
        one has others to fetch first: those it claimed, else those on the nearest furniture."""
        others = [f for f in self._fetchers(obs) if self._works(obs, f)]
        if not others:
            return None
        known = [o for o in obs.objects if self._fetchable(obs, o)]
        mine = {o.on for o in known if self.objects.get(o.name) == obs.robot}
        free = [o for o in known if o.name not in self.objects]
        if not mine and free:
            mine = {self._nearest(obs, free).on}  # kept for itself
        free = [o for o in free if o.on not in mine]
        if not free:
            return None
        give = self._same_place(obs, max(free, key=lambda o: self._distance(obs, o)))
        to = others[self.handoffs % len(others)]
        self.handoffs += 1
        for name in give:
            self.objects[name] = to
        return self._decision(Communicate(to=to, content=handoff_sentence(give, to)))

    # ---- what a fetcher could fetch (the fetcher decides: heuristic_fetcher.py)
    def _fetchable(self, obs: Observation, o: ObjectView) -> bool:
        raise NotImplementedError

    @staticmethod
    def _distance(obs: Observation, o: ObjectView) -> float:
        here = obs.status.base
        return 0.0 if here is None else _dist2(o.position, (here.x, here.y))

    def _nearest(self, obs: Observation, objs: list[ObjectView]) -> ObjectView:
        return min(objs, key=lambda o: self._distance(obs, o))
