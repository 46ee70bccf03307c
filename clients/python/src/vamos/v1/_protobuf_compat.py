"""What ``monitor_pb2`` needs from protobuf, on every protobuf runtime from 3.12 on.

protoc's Python output today builds its classes with ``google.protobuf.internal.builder``
(protobuf >= 3.20) and refuses, through ``runtime_version`` (protobuf >= 5.26), any
runtime older than the protoc that wrote it. ROS 2 Humble runs on Ubuntu 22.04, whose
``python3-protobuf`` is 3.12.4; Jazzy on Ubuntu 24.04, whose ``python3-protobuf`` 3.21.12
is the 4.21 Python API. ``generate_stubs.py`` therefore drops the version check and points
the generated module here: on protobuf >= 3.20 these functions are the builder's own; on
3.12 to 3.19 they build the same module attributes (descriptors ``_NAME``, message
classes, enum wrappers and values) the way protoc of those releases did, with
``reflection.GeneratedProtocolMessageType``.

The message encoding does not depend on the runtime: tests/test_stubs_old_protobuf.py
imports the stubs under protobuf 3.12.4, 3.20.3 and 4.21.12 and checks the bytes against
the current runtime's.
"""

from __future__ import annotations

from typing import Any

from google.protobuf import descriptor_pool

try:  # protobuf >= 3.20
    from google.protobuf.internal import builder as _builder
except ImportError:  # pragma: no cover - exercised in a subprocess with protobuf < 3.20
    _builder = None


def AddSerializedFile(serialized: bytes) -> Any:  # noqa: N802 - protobuf's name
    """Adds a serialized ``FileDescriptorProto`` to the default pool; returns its
    ``FileDescriptor`` (protobuf < 3.19's pool returns nothing: looked up by name)."""
    pool = descriptor_pool.Default()
    file_des = pool.AddSerializedFile(serialized)
    if file_des is None:
        from google.protobuf import descriptor_pb2

        file_des = pool.FindFileByName(descriptor_pb2.FileDescriptorProto.FromString(serialized).name)
    return file_des


def _nested_descriptors(msg_des: Any, prefix: str, module: dict[str, Any]) -> None:
    for name, nested in msg_des.nested_types_by_name.items():
        module[prefix + name.upper()] = nested
        _nested_descriptors(nested, prefix + name.upper() + "_", module)
    for enum_des in msg_des.enum_types:
        module[prefix + enum_des.name.upper()] = enum_des


def BuildMessageAndEnumDescriptors(file_des: Any, module: dict[str, Any]) -> None:  # noqa: N802
    """``_MESSAGE``, ``_MESSAGE_NESTED`` and ``_MESSAGE_ENUM`` descriptors in ``module``."""
    if _builder is not None:
        _builder.BuildMessageAndEnumDescriptors(file_des, module)
        return
    for name, msg_des in file_des.message_types_by_name.items():
        module["_" + name.upper()] = msg_des
        _nested_descriptors(msg_des, "_" + name.upper() + "_", module)


def BuildTopDescriptorsAndMessages(file_des: Any, module_name: str, module: dict[str, Any]) -> None:  # noqa: N802
    """Top-level enums (wrapper and values), message classes and service descriptors in
    ``module``."""
    if _builder is not None:
        _builder.BuildTopDescriptorsAndMessages(file_des, module_name, module)
        return
    from google.protobuf import message, reflection, symbol_database
    from google.protobuf.internal import enum_type_wrapper

    if file_des.extensions_by_name:
        raise NotImplementedError("extensions are not built on protobuf < 3.20")
    sym_db = symbol_database.Default()

    def message_class(msg_des: Any) -> Any:
        members: dict[str, Any] = {name: message_class(nested) for name, nested in msg_des.nested_types_by_name.items()}
        members["DESCRIPTOR"] = msg_des
        members["__module__"] = module_name
        cls = reflection.GeneratedProtocolMessageType(str(msg_des.name), (message.Message,), members)
        sym_db.RegisterMessage(cls)
        return cls

    for name, enum_des in file_des.enum_types_by_name.items():
        module["_" + name.upper()] = enum_des
        module[name] = enum_type_wrapper.EnumTypeWrapper(enum_des)
        for value in enum_des.values:
            module[value.name] = value.number
    for name, msg_des in file_des.message_types_by_name.items():
        module[name] = message_class(msg_des)
    for name, service in file_des.services_by_name.items():
        module["_" + name.upper()] = service
