"""The OCM hub's client (issue 47): a hub that does not answer is given up on at once for a
while, so the reconciles of a site cut off from it do not each wait out the timeout."""

from __future__ import annotations

import json

import pytest
import urllib3
from kubernetes import client

from fogfleet.adapters.hub import HUB_BACKOFF, HUB_TIMEOUT, HubClient
from fogfleet.errors import DependencyUnavailable


class Response:
    def __init__(self, status: int, body: object) -> None:
        self.status = status
        self.body = json.dumps(body).encode()

    def read(self) -> bytes:
        return self.body


def test_after_a_request_without_an_answer_the_hub_is_refused_at_once_until_the_backoff_ends(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    now = [100.0]
    hub = HubClient(
        client.ApiClient(client.Configuration(host="https://hub:443")), clock=lambda: now[0]
    )
    calls: list[object] = []
    answers: list[object] = [
        urllib3.exceptions.ReadTimeoutError(None, "/", "timed out"),  # type: ignore[arg-type]
        Response(200, {"items": [{"metadata": {"name": "cloud"}}]}),
    ]

    def call_api(*args: object, **kwargs: object) -> object:
        calls.append(kwargs.get("_request_timeout"))
        answer = answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer

    monkeypatch.setattr(hub.api, "call_api", call_api)
    with pytest.raises(DependencyUnavailable):
        hub.list_managed_clusters()
    assert calls == [HUB_TIMEOUT]
    now[0] += HUB_BACKOFF - 1
    with pytest.raises(DependencyUnavailable, match="did not answer"):
        hub.list_works("cloud", {})
    assert len(calls) == 1  # refused without a request
    now[0] += 2
    assert [mc["metadata"]["name"] for mc in hub.list_managed_clusters()] == ["cloud"]
    assert len(calls) == 2
