"""A request cannot make the server open a file: ``observer: {oem|spice}`` and ``attitude:
{aem|spice}`` naming server paths get a one-line 4xx, and the service keeps answering."""

from __future__ import annotations

import json

import pytest

from .conftest import small_scene
from .test_bad_requests import _error, _post


@pytest.mark.parametrize("change, field", [
    ({"observer": {"spice": {"kernels": ["/etc/hosts"], "body": "399"}}}, "observer.spice.kernels"),
    ({"attitude": {"spice": {"kernels": ["/etc/hosts"], "frame": "CAM"}}}, "attitude.spice.kernels"),
    ({"observer": {"oem": "/etc/hosts"}}, "observer.oem"),
    ({"attitude": {"aem": "/etc/hosts"}}, "attitude.aem"),
])
def test_a_request_naming_a_file_is_refused_and_the_service_answers_on(server, change, field):
    mapping = {**small_scene(), **change}
    status, _, data = _post(server.url, json.dumps(mapping).encode())
    msg = _error(status, data)
    assert field in msg and "cannot name a file" in msg
    status, _, _ = _post(server.url, json.dumps(small_scene()).encode())
    assert status == 200
