"""The OpenAPI document of protocol version 1 (served at ``/v1/openapi.json``, checked into docs/service.md)."""

from __future__ import annotations

from .protocol import API_PREFIX, MEDIA_TYPES, MULTIPART, OUTPUTS, SCENE_KEYS

_ERROR = {"description": "one line naming the bad field and what is allowed",
          "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}}


def openapi_document() -> dict:
    """The document, as a JSON-ready dict (key order fixed, so its JSON text is stable)."""
    scene_props = {k: {"type": "object" if k != "epoch" else "string",
                       "description": f"as the '{k}' key of a scene file (docs/datasets.md)"} for k in SCENE_KEYS}
    scene_props["outputs"] = {"type": "array", "items": {"type": "string", "enum": list(OUTPUTS)}, "uniqueItems": True,
                              "minItems": 1, "default": ["png", "truth"],
                              "description": "what to return, in this order; screen_png only when the server has a facility"}
    return {
        "openapi": "3.1.0",
        "info": {"title": "skynav render service", "version": "1",
                 "description": "Frames of a scene mapping, byte-identical to the files of `skynav render`."},
        "paths": {
            f"{API_PREFIX}/health": {"get": {
                "summary": "the server is ready", "operationId": "health",
                "responses": {"200": {"description": "ready", "content": {"application/json": {
                    "schema": {"$ref": "#/components/schemas/Health"}}}}}}},
            f"{API_PREFIX}/render": {"post": {
                "summary": "render one frame of a scene mapping", "operationId": "render",
                "security": [{}, {"bearer": []}],
                "requestBody": {"required": True, "content": {"application/json": {
                    "schema": {"$ref": "#/components/schemas/RenderRequest"}}}},
                "responses": {
                    "200": {"description": "one output: its bytes with its media type; several: a multipart/mixed "
                                           "body, one part per output in the order asked, each with Content-Type, "
                                           "Content-Length and Content-Disposition: inline; name=\"OUTPUT\"",
                            "headers": {"Server-Timing": {"schema": {"type": "string"}, "description":
                                                          "milliseconds: queue (waiting for a worker), render (the "
                                                          "worker's frame), service (the rest of the server's time)"},
                                        "Skynav-Warnings": {"schema": {"type": "string"},
                                                            "description": "the scene's warnings, ' | '-separated"}},
                            "content": {**{t: {"schema": {"type": "string", "format": "binary"}}
                                           for t in dict.fromkeys(MEDIA_TYPES.values()) if t != "application/json"},
                                        "application/json": {"schema": {"type": "object",
                                                                        "description": "ground truth, skynav.frame/2"}},
                                        MULTIPART: {"schema": {"type": "string", "format": "binary"}}}},
                    "400": _ERROR, "401": _ERROR, "413": _ERROR, "415": _ERROR, "503": _ERROR}}},
            f"{API_PREFIX}/openapi.json": {"get": {
                "summary": "this document", "operationId": "openapi",
                "responses": {"200": {"description": "OpenAPI 3.1", "content": {"application/json": {}}}}}},
        },
        "components": {
            "schemas": {
                "RenderRequest": {"type": "object", "required": ["epoch", "observer"], "additionalProperties": False,
                                  "properties": scene_props},
                "Health": {"type": "object", "properties": {
                    "status": {"type": "string", "enum": ["ok"]}, "api": {"type": "string"},
                    "workers": {"type": "integer"}, "busy": {"type": "integer"}, "waiting": {"type": "integer"},
                    "outputs": {"type": "array", "items": {"type": "string"}},
                    "facility": {"type": ["string", "null"]}}},
                "Error": {"type": "object", "required": ["error"], "properties": {"error": {"type": "string"}}},
            },
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer",
                                           "description": "required when the server was started with --token"}},
        },
    }


if __name__ == "__main__":   # the block of docs/service.md: python -m skynav.service.openapi
    import json

    print(json.dumps(openapi_document(), indent=2))
