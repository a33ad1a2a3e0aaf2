"""The wire format of render answers and requests, checked against independent parsers.

A multipart answer is parsed by the client's parser and by the standard library's e-mail parser
(what ``http.client``, urllib and requests users read multipart bodies with); a request body made
by the client is sent to a real server.
"""

from __future__ import annotations

import email.parser
import email.policy
import json
import math

import numpy as np
import pytest

from skynav.service.client import ServiceError, parse_multipart, request_body
from skynav.service.protocol import BOUNDARY, answer_chunks

from .conftest import small_scene


def _email_parts(body: bytes, content_type: str) -> dict:
    msg = email.parser.BytesParser(policy=email.policy.HTTP).parsebytes(
        b"Content-Type: " + content_type.encode("ascii") + b"\r\n\r\n" + body)
    return {part.get_param("name", header="content-disposition"): part.get_payload(decode=True)
            for part in msg.iter_parts()}


@pytest.mark.parametrize("truth_text", [
    '--' + BOUNDARY,                     # the delimiter itself, in a string
    'x\n--' + BOUNDARY + '--\r\n',       # after a line break (escaped in the JSON text)
])
def test_a_json_part_keeps_the_fixed_boundary_and_both_parsers_agree(truth_text):
    """The truth is not searched for the boundary (a JSON text holds no delimiter line): the answer
    keeps the fixed boundary even when a string in the truth spells it, and the parts come back
    byte for byte through the client's parser and the e-mail parser."""
    parts = {"png": b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 8,
             "truth": json.dumps({"schema": "skynav.frame/2", "name": truth_text}, indent=2).encode()}
    chunks, ctype = answer_chunks(parts)
    assert f'boundary="{BOUNDARY}"' in ctype
    body = b"".join(chunks)
    assert parse_multipart(body, ctype) == parts
    assert parse_multipart(memoryview(bytearray(body)), ctype) == parts
    email_parts = _email_parts(body, ctype)
    assert email_parts["png"] == parts["png"]
    assert email_parts["truth"].rstrip(b"\r\n") == parts["truth"]


def test_an_image_part_that_holds_the_boundary_gets_a_fresh_one():
    parts = {"png": b"\x89PNG\r\n--" + BOUNDARY.encode() + b"\r\n" + bytes(range(256)),
             "truth": b'{"schema": "skynav.frame/2"}'}
    chunks, ctype = answer_chunks(parts)
    assert BOUNDARY not in ctype
    body = b"".join(chunks)
    assert parse_multipart(body, ctype) == parts
    assert _email_parts(body, ctype)["png"] == parts["png"]


def test_request_bodies_read_back_as_the_mapping():
    """orjson's text where it holds the mapping, the standard library's otherwise; either reads
    back (standard-library JSON) as the mapping and its outputs."""
    scene = small_scene(size=64)
    for mapping in (scene, {**scene, "attitude": {"q_cam_icrs": [np.float64(0.5)] * 4}}):
        doc = json.loads(request_body(mapping, ("png", "truth")))
        assert doc == {**json.loads(json.dumps(mapping, default=float)), "outputs": ["png", "truth"]}
    body = request_body({**scene, "camera": {**scene["camera"], "exposure_s": math.nan}}, ("png",))
    assert b"NaN" in body   # not orjson's null: the server refuses it by name


def test_numpy_numbers_and_non_finite_values_through_the_server(client):
    """A mapping with numpy numbers renders the same frame as with plain floats; a non-finite
    number is a 400 naming the request body, as a raw NaN in JSON is."""
    scene = small_scene(size=64)
    want = client.render(scene, outputs=("png",)).png
    with_numpy = {**scene, "observer": {k: [np.float64(x) for x in v] if isinstance(v, list) else v
                                        for k, v in scene["observer"].items()}}
    assert client.render(with_numpy, outputs=("png",)).png == want
    with pytest.raises(ServiceError) as e:
        client.render({**scene, "camera": {**scene["camera"], "exposure_s": math.inf}}, outputs=("png",))
    assert e.value.status == 400 and "request body" in str(e.value) and "Infinity" in str(e.value)
