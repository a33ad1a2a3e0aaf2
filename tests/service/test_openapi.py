"""The OpenAPI document that docs/service.md shows is the one the server serves."""

from __future__ import annotations

import json
import re
import urllib.request
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "service.md"


def documented_openapi() -> dict:
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## The OpenAPI document", 1)[1]
    block = re.search(r"```json\n(.*?)\n```", section, re.S)
    return json.loads(block.group(1))


def test_docs_show_the_served_openapi_document(server):
    with urllib.request.urlopen(f"{server.url}/v1/openapi.json", timeout=30) as r:
        served = json.loads(r.read())
    assert documented_openapi() == served, "regenerate docs/service.md's block: python -m skynav.service.openapi"
    assert set(served["paths"]) == {"/v1/health", "/v1/render", "/v1/openapi.json"}
