#!/usr/bin/env python3
"""Sends one request to hydrometrad's control service (docs/ipc.md, "Control") and prints the
response.

    pip install 'iceoryx2==0.10.*'
    python3 ipc/examples/python/control.py record_status
    python3 ipc/examples/python/control.py load_scene myoma-figo1 --json
    python3 ipc/examples/python/control.py new_procedure --prefix hydrometra/v1

Exit code 0 when the daemon answers `ok`, 1 for any other result, 2 when no daemon answers.
"""

import argparse
import ctypes
import json
import sys
import time

import iceoryx2 as iox2

COMMANDS = {
    "new_procedure": 1,
    "load_scene": 2,
    "record_start": 3,
    "record_stop": 4,
    "record_status": 5,
}
RESULTS = ["ok", "bad_request", "not_found", "unavailable", "failed", "busy"]
RESPONSE_TIMEOUT_S = 5.0  # hydrometra_ipc::control::RESPONSE_TIMEOUT


class ControlRequest(ctypes.Structure):
    """hydrometra.v1.ControlRequest: 272 bytes, 4-byte aligned."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("command", ctypes.c_uint32),
        ("argument_len", ctypes.c_uint32),
        ("reserved0", ctypes.c_uint32),
        ("argument", ctypes.c_uint8 * 256),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; carries the schema version."""
        return "hydrometra.v1.ControlRequest"


class ControlResponse(ctypes.Structure):
    """hydrometra.v1.ControlResponse: 560 bytes, 8-byte aligned."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("command", ctypes.c_uint32),
        ("result", ctypes.c_uint32),
        ("recording", ctypes.c_uint32),
        ("procedure_id", ctypes.c_uint64),
        ("recorded_messages", ctypes.c_uint64),
        ("recordings_finished", ctypes.c_uint64),
        ("message_len", ctypes.c_uint32),
        ("recording_path_len", ctypes.c_uint32),
        ("message", ctypes.c_uint8 * 256),
        ("recording_path", ctypes.c_uint8 * 256),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; carries the schema version."""
        return "hydrometra.v1.ControlResponse"


assert ctypes.sizeof(ControlRequest) == 272, ctypes.sizeof(ControlRequest)
assert ctypes.sizeof(ControlResponse) == 560, ctypes.sizeof(ControlResponse)


def text(array, length: int) -> str:
    return bytes(array[: min(length, 256)]).decode("utf-8", errors="replace")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=sorted(COMMANDS))
    parser.add_argument("argument", nargs="?", default="", help="the scene for load_scene")
    parser.add_argument("--prefix", default="hydrometra/v1", help="service prefix")
    parser.add_argument("--json", action="store_true", help="print the response as JSON")
    args = parser.parse_args()

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    name = f"{args.prefix}/control"
    try:
        service = (
            node.service_builder(iox2.ServiceName.new(name))
            .request_response(ControlRequest, ControlResponse)
            .open()
        )
    except iox2.RequestResponseOpenError as error:
        print(f"error: cannot open {name} ({error!r}): is hydrometrad running with this prefix?", file=sys.stderr)
        return 2
    client = service.client_builder().create()

    argument = args.argument.encode("utf-8")
    if len(argument) > 256:
        print("error: the argument is longer than 256 bytes", file=sys.stderr)
        return 2
    request = ControlRequest(schema_version=1, command=COMMANDS[args.command], argument_len=len(argument))
    ctypes.memmove(request.argument, argument, len(argument))
    pending = client.send_copy(request)
    if pending.number_of_server_connections == 0:
        print(f"error: no hydrometrad serves {name}", file=sys.stderr)
        return 2

    deadline = time.monotonic() + RESPONSE_TIMEOUT_S
    while time.monotonic() < deadline:
        response = pending.receive()
        if response is not None:
            r = response.payload().contents
            result = RESULTS[r.result] if r.result < len(RESULTS) else f"unknown ({r.result})"
            fields = {
                "result": result,
                "message": text(r.message, r.message_len),
                "procedure_id": r.procedure_id,
                "recording": bool(r.recording),
                "recording_path": text(r.recording_path, r.recording_path_len),
                "recorded_messages": r.recorded_messages,
                "recordings_finished": r.recordings_finished,
            }
            if args.json:
                print(json.dumps(fields))
            else:
                print(f"{result}: {fields['message']}")
            return 0 if r.result == 0 else 1
        time.sleep(0.005)
    print(f"error: no response from {name} within {RESPONSE_TIMEOUT_S} s", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
