"""Fuzz the API from its own OpenAPI schema with schemathesis (valid and invalid inputs): no 5xx, ever, and every
error is the JSON error body.

Schemathesis generates the cases (hypothesis strategies built from /openapi.json) and sends them to a real
server; its pytest plug-in is not used (it reaches into pytest internals that pytest 9 no longer has).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="schemathesis is not installed (pip install schemathesis)")
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis.checks import not_a_server_error
from schemathesis.generation.modes import GenerationMode

from ..service_server import ServiceServer

pytestmark = pytest.mark.timeout(240)
EXAMPLES = 40  # per operation and mode: ~10 operations x 2 modes x 40 cases, well under a minute on 2 cores


@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("fuzz") / "data"
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_QUEUE_SIZE": "4",
        "COLONLIGHT_MAX_UPLOAD_MB": "1",
        "COLONLIGHT_SYNC_MAX_SECONDS": "2",
    }
    with ServiceServer(data, env) as srv:
        yield srv


def fuzz_operation(
    operation,
    mode: GenerationMode,
    url: str,
    failures: list[str],  # type: ignore[no-untyped-def]
    seen: dict[str, set[int]],
) -> None:
    """Send EXAMPLES generated requests for one operation; record failures instead of stopping at the first."""
    label = f"{operation.method.upper()} {operation.path}"

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(
        max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True, database=None
    )
    def run(case) -> None:  # type: ignore[no-untyped-def]
        response = case.call(base_url=url, timeout=60)
        seen.setdefault(label, set()).add(response.status_code)
        try:
            case.validate_response(response, checks=[not_a_server_error])
        except AssertionError as exc:
            failures.append(f"{label}: {str(exc)[:500]}")
            return
        if response.status_code >= 400:
            raw = response.headers.get("content-type", "")
            ctype = raw[0] if isinstance(raw, list) else raw
            if not ctype.startswith("application/json"):
                failures.append(f"{label}: {response.status_code} with {ctype}: {response.text[:200]}")
            elif response.status_code != 503 and not response.json().get("message"):
                failures.append(f"{label}: error without a message: {response.text[:200]}")

    try:
        run()
    except Unsatisfiable:
        assert mode == GenerationMode.NEGATIVE, label  # nothing to get wrong in a request without inputs


@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE], ids=["valid", "invalid"])
def test_no_server_errors(fuzz_server: ServiceServer, mode: GenerationMode) -> None:
    schema = schemathesis.openapi.from_url(fuzz_server.url + "/openapi.json")
    failures: list[str] = []
    seen: dict[str, set[int]] = {}
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 9
    for operation in operations:
        fuzz_operation(operation, mode, fuzz_server.url, failures, seen)
    assert not failures, "\n".join(failures[:20])
    assert not any(code >= 500 and code != 503 for codes in seen.values() for code in codes), seen
    print({k: sorted(v) for k, v in seen.items()})
