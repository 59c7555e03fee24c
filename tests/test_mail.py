"""The mailroom under two threads at once (issue 32): the simulator's thread sends and learns
while the event loop's re-attaches the receiver (delivers its inbox, puts back what no
observation carried). No message and nothing a message tells may be lost or told twice.

The race is a few bytecodes wide, so the test widens the odds (the interpreter switches threads
every microsecond) and sends many messages; on the unguarded mailroom it lost messages (8 to 259 of 20,000) in each of
the three runs tried. Guarded, it cannot fail. tests/test_world_service.py re-attaches a robot
during a held tick over the real bus."""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Iterator

import pytest

from mhrc.world.mail import Mailroom

SENDS = 20_000


@pytest.fixture
def busy_switching() -> Iterator[None]:
    """Threads switch as often as the interpreter allows, so an unguarded read-modify-write is
    interrupted many times a run."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def test_a_message_sent_while_its_receiver_reattaches_is_kept_and_told_once(busy_switching: None) -> None:
    told: list[str] = []

    def teller(receiver: str, sender: str, text: str) -> Callable[[], None]:
        return lambda: told.append(text)

    mail = Mailroom(["alice", "bob"], teller)
    sent_all = threading.Event()

    def simulator() -> None:  # the world's worker thread: sends, and learns at each use
        for i in range(SENDS):
            mail.send("bob", "alice", f"m{i}", 0)
            if i % 7 == 0:
                mail.learn()
            if i % 101 == 0:
                mail.delivered(mail.robots)  # a lockstep batch delivers its messages
        sent_all.set()

    carried: list[str] = []
    thread = threading.Thread(target=simulator)
    thread.start()
    try:
        rounds = 0
        while not sent_all.is_set():  # the event loop: alice attaches again and again
            rounds += 1
            messages = mail.deliver("alice")
            if rounds % 2:
                mail.hold("alice", messages)  # the observation did not carry them (as a scheduler puts them back)
            else:
                carried += [m.content for m in messages]
    finally:
        thread.join()
    carried += [m.content for m in mail.take_all()["alice"]]
    mail.learn()

    expected = [f"m{i}" for i in range(SENDS)]
    assert sorted(carried) == sorted(expected), (
        f"{SENDS - len(set(carried))} messages lost, {len(carried) - len(set(carried))} doubled"
    )
    assert sorted(told) == sorted(expected), (
        f"{SENDS - len(set(told))} tellings lost, {len(told) - len(set(told))} doubled"
    )
    assert carried == sorted(carried, key=lambda c: int(c[1:])), "messages reach the robot in the order sent"


def test_what_a_message_tells_is_learned_with_the_observation_that_carries_it() -> None:
    """`deliver` takes the inbox and makes its tellings due in one step: a message sent after it
    is neither in that observation nor known to it."""
    told: list[str] = []
    mail = Mailroom(["alice", "bob"], lambda receiver, sender, text: lambda: told.append(text))
    mail.send("bob", "alice", "first", 0)
    carried = mail.deliver("alice")
    mail.send("bob", "alice", "second", 0)  # while the observation is being made
    mail.learn()  # the observation of the attach reply
    assert [m.content for m in carried] == ["first"] and told == ["first"]
    assert [m.content for m in mail.take_all()["alice"]] == ["second"]
    mail.learn()
    assert told == ["first", "second"]
