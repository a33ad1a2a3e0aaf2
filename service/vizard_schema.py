"""The part of Basilisk's ``VizMessage`` (package ``vizProtobufferMessage``, proto3) that the
Vizard endpoint reads, declared here with protobuf's descriptor API.

Basilisk's ``vizInterface`` sends one ``VizMessage`` with each ``SIM_UPDATE``. Its layout is
Basilisk's documented schema (``vizMessage.proto``); the fields below carry its names, numbers
and types. Only the messages and fields the endpoint uses are declared: protobuf keeps the others
as unknown fields when it parses a message, so a newer Basilisk that adds fields still parses.

Units, as ``vizInterface`` writes them: positions in m, velocities in m/s, the spacecraft's
``rotation`` the MRP sigma_BN (the schema's comment says DCM; the code writes sigma_BN), a body's
``rotation`` the 9 elements of its J2000-to-body-fixed DCM, row by row, ``radiusEq`` in km,
``mu`` in km^3/s^2, the camera's ``fieldOfView`` in degrees edge to edge along the image height,
``resolution`` [width, height] px, ``cameraPos_B`` in m on the body frame, ``cameraDir_B`` the
MRP of Unity's camera frame relative to the body frame, ``renderRate`` in ns, the time stamp's
``simTimeElapsed`` in ns and the epoch a UTC calendar date.
"""

from __future__ import annotations

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

PACKAGE = "vizProtobufferMessage"

_T = descriptor_pb2.FieldDescriptorProto
_SCALARS = {"double": _T.TYPE_DOUBLE, "int64": _T.TYPE_INT64, "uint64": _T.TYPE_UINT64, "int32": _T.TYPE_INT32,
            "string": _T.TYPE_STRING, "bool": _T.TYPE_BOOL}

# (message, [(field, number, type, repeated)]), each nested in VizMessage as in Basilisk's schema; a
# type that is not a scalar is another of these messages
_NESTED = (
    ("TimeStamp", [("frameNumber", 1, "int64", False), ("simTimeElapsed", 2, "double", False)]),
    ("EpochDateTime", [("year", 1, "int32", False), ("month", 2, "int32", False), ("day", 3, "int32", False),
                       ("hours", 4, "int32", False), ("minutes", 5, "int32", False), ("seconds", 6, "double", False)]),
    ("CelestialBody", [("bodyName", 1, "string", False), ("position", 2, "double", True),
                       ("velocity", 3, "double", True), ("rotation", 4, "double", True), ("mu", 5, "double", False),
                       ("radiusEq", 6, "double", False), ("radiusRatio", 7, "double", False),
                       ("modelDictionaryKey", 8, "string", False)]),
    ("Spacecraft", [("spacecraftName", 1, "string", False), ("position", 2, "double", True),
                    ("velocity", 3, "double", True), ("rotation", 4, "double", True)]),
    ("CameraConfig", [("cameraID", 1, "int64", False), ("parentName", 2, "string", False),
                      ("fieldOfView", 3, "double", False), ("resolution", 4, "int64", True),
                      ("cameraPos_B", 7, "double", True), ("cameraDir_B", 8, "double", True),
                      ("renderRate", 9, "uint64", False), ("skybox", 10, "string", False),
                      ("renderMode", 16, "int64", False)]),
)
_VIZ_MESSAGE = [("currentTime", 1, "TimeStamp", False), ("celestialBodies", 2, "CelestialBody", True),
                ("spacecraft", 3, "Spacecraft", True), ("cameras", 4, "CameraConfig", True),
                ("epoch", 8, "EpochDateTime", False)]


def _add_fields(msg, fields) -> None:
    for field, number, kind, repeated in fields:
        f = msg.field.add(name=field, number=number, label=_T.LABEL_REPEATED if repeated else _T.LABEL_OPTIONAL)
        if kind in _SCALARS:
            f.type = _SCALARS[kind]
        else:
            f.type, f.type_name = _T.TYPE_MESSAGE, f".{PACKAGE}.VizMessage.{kind}"


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    fd = descriptor_pb2.FileDescriptorProto(name="skynav_vizard/vizMessage.proto", package=PACKAGE, syntax="proto3")
    top = fd.message_type.add(name="VizMessage")
    _add_fields(top, _VIZ_MESSAGE)
    for name, fields in _NESTED:
        _add_fields(top.nested_type.add(name=name), fields)
    return fd


def _classes() -> dict:
    pool = descriptor_pool.DescriptorPool()    # a pool of its own: never clashes with another copy of the schema
    top = pool.Add(_file_descriptor()).message_types_by_name["VizMessage"]
    classes = {name: message_factory.GetMessageClass(top.nested_types_by_name[name]) for name, _ in _NESTED}
    classes["VizMessage"] = message_factory.GetMessageClass(top)
    return classes


_CLASSES = _classes()
VizMessage = _CLASSES["VizMessage"]
TimeStamp = _CLASSES["TimeStamp"]
EpochDateTime = _CLASSES["EpochDateTime"]
CelestialBody = _CLASSES["CelestialBody"]
Spacecraft = _CLASSES["Spacecraft"]
CameraConfig = _CLASSES["CameraConfig"]
