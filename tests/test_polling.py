"""`mhrc.core.polling.poll`, the one polling helper (find_run, alive_tokens, open_client use it)."""

from __future__ import annotations

import pytest

from mhrc.core.polling import poll


def attempts(*answers: object) -> tuple[list[int], object]:
    calls: list[int] = []

    async def attempt() -> object:
        calls.append(len(calls))
        return answers[len(calls) - 1]

    return calls, attempt


async def test_it_asks_again_until_an_answer_comes() -> None:
    calls, attempt = attempts(None, None, ["world"], ["late"])
    assert await poll(attempt, timeout=60, every=0) == ["world"]  # type: ignore[arg-type]
    assert len(calls) == 3


async def test_an_empty_answer_is_an_answer_only_none_asks_again() -> None:
    calls, attempt = attempts([], ["world"])
    assert await poll(attempt, timeout=60, every=0) == []  # type: ignore[arg-type]
    assert len(calls) == 1


async def test_past_the_deadline_it_gives_none_after_one_attempt_at_least() -> None:
    calls, attempt = attempts(None, "never asked")
    assert await poll(attempt, timeout=0, every=0.1) is None  # type: ignore[arg-type]
    assert len(calls) == 1


async def test_an_error_ends_the_polling() -> None:
    async def attempt() -> None:
        raise LookupError("refused for good")

    with pytest.raises(LookupError, match="refused for good"):
        await poll(attempt, timeout=60, every=0)
