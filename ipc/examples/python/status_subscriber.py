#!/usr/bin/env python3
"""Reads hydrometrad's status over iceoryx2 shared memory (the renderer contract, docs/ipc.md).

    pip install 'iceoryx2==0.10.*'
    python3 ipc/examples/python/status_subscriber.py                 # live, until Ctrl-C
    python3 ipc/examples/python/status_subscriber.py --count 5 --json

The payload is the repr(C) struct `hydrometra.v1.Status` mirrored with ctypes below. The type name
(with the schema version), the size and the alignment must match the daemon's exactly, otherwise
opening the service fails with an incompatible-type error instead of misreading bytes.
"""

import argparse
import ctypes
import json
import math
import sys
import time

import iceoryx2 as iox2

PA_PER_MMHG = 133.322387415  # hydrometra_units::PA_PER_MMHG (ipc/tests/python_constants.rs)
LINK_STATES = ["disconnected", "handshaking", "connected", "stale", "incompatible"]
EVENT_STATUS = 1  # event id: a new status was published
EVENT_SHUTDOWN = 15  # event id: the daemon is stopping


class Status(ctypes.Structure):
    """hydrometra.v1.Status: 752 bytes, 8-byte aligned, native (little-endian) byte order."""

    _fields_ = [
        ("schema_version", ctypes.c_uint32),
        ("size_bytes", ctypes.c_uint32),
        ("sequence", ctypes.c_uint64),
        ("run_id", ctypes.c_uint64),
        ("sim_time_s", ctypes.c_double),
        ("publish_monotonic_ns", ctypes.c_uint64),
        ("link_frames", ctypes.c_uint64),
        ("link_crc_errors", ctypes.c_uint64),
        ("link_malformed", ctypes.c_uint64),
        ("link_sequence_gaps", ctypes.c_uint64),
        ("link_resyncs", ctypes.c_uint64),
        ("link_reconnects", ctypes.c_uint64),
        ("link_clamped_values", ctypes.c_uint64),
        ("link_device_faults", ctypes.c_uint64),
        ("last_sample_age_s", ctypes.c_double),
        ("rig_device_time_us", ctypes.c_uint64),
        ("rig_valve_in_opening", ctypes.c_double),
        ("rig_valve_out_opening", ctypes.c_double),
        ("rig_pump_set_pressure_pa", ctypes.c_double),
        ("valve_in_opening", ctypes.c_double),
        ("valve_out_opening", ctypes.c_double),
        ("pump_set_pressure_pa", ctypes.c_double),
        ("scope_tip_position_m", ctypes.c_double * 3),
        ("scope_view_direction", ctypes.c_double * 3),
        ("scope_orientation_wxyz", ctypes.c_double * 4),
        ("alarm_bits", ctypes.c_uint64),
        ("tick_rate_hz", ctypes.c_double),
        ("ticks", ctypes.c_uint64),
        ("deadline_misses", ctypes.c_uint64),
        ("tick_work_max_s", ctypes.c_double),
        ("latency_p50_s", ctypes.c_double),
        ("latency_p99_s", ctypes.c_double),
        ("latency_max_s", ctypes.c_double),
        ("latency_samples", ctypes.c_uint64),
        ("statuses_dropped", ctypes.c_uint64),
        ("link_state", ctypes.c_uint32),
        ("rig_sequence", ctypes.c_uint32),
        ("buttons", ctypes.c_uint32),
        ("scope_pose_valid", ctypes.c_uint32),
        ("safe_state", ctypes.c_uint32),
        ("reserved0", ctypes.c_uint32),
        ("cavity_pressure_pa", ctypes.c_double),
        ("cavity_volume_m3", ctypes.c_double),
        ("inflow_m3_per_s", ctypes.c_double),
        ("outflow_m3_per_s", ctypes.c_double),
        ("leak_m3_per_s", ctypes.c_double),
        ("absorption_m3_per_s", ctypes.c_double),
        ("perforation_m3_per_s", ctypes.c_double),
        ("inflow_port_velocity_m_per_s", ctypes.c_double),
        ("outflow_port_velocity_m_per_s", ctypes.c_double),
        ("fluid_in_m3", ctypes.c_double),
        ("fluid_collected_m3", ctypes.c_double),
        ("deficit_m3", ctypes.c_double),
        ("deficit_rate_m3_per_s", ctypes.c_double),
        ("deficit_limit_m3", ctypes.c_double),
        ("procedure_id", ctypes.c_uint64),
        ("procedure_time_s", ctypes.c_double),
        ("deficit_warning_stage", ctypes.c_uint64),
        ("hydraulic_flags", ctypes.c_uint64),
        ("link_down_reason", ctypes.c_uint32),
        ("link_down_detail", ctypes.c_uint32),
        ("scene_state", ctypes.c_uint64),
        ("scene_frames", ctypes.c_uint64),
        ("scene_stage_runs", ctypes.c_uint64 * 7),
        ("scene_stage_skips", ctypes.c_uint64 * 7),
        ("scene_stage_p99_s", ctypes.c_double * 7),
        ("scene_step_p99_s", ctypes.c_double),
        ("view_clarity", ctypes.c_double),
        ("cavity_surface_volume_m3", ctypes.c_double),
        ("inflow_port_open_fraction", ctypes.c_double),
        ("realtime_mode", ctypes.c_uint32),
        ("scene_degradation", ctypes.c_uint32),
        ("scene_frames_late", ctypes.c_uint64),
        ("scene_frames_skipped", ctypes.c_uint64),
        ("status_gap_max_s", ctypes.c_double),
    ]

    @staticmethod
    def type_name() -> str:
        """The iceoryx2 type name; carries the schema version."""
        return "hydrometra.v1.Status"


assert ctypes.sizeof(Status) == 752, ctypes.sizeof(Status)


def as_dict(s: Status) -> dict:
    """Every field as plain Python values (NaN -> None)."""
    out = {}
    for name, _ in Status._fields_:
        value = getattr(s, name)
        if isinstance(value, ctypes.Array):
            value = list(value)
        if isinstance(value, float) and math.isnan(value):
            value = None
        out[name] = value
    out["link_state_name"] = LINK_STATES[s.link_state] if s.link_state < len(LINK_STATES) else "unknown"
    out["pump_set_pressure_mmhg"] = s.pump_set_pressure_pa / PA_PER_MMHG
    return out


def describe(s: Status) -> str:
    state = LINK_STATES[s.link_state] if s.link_state < len(LINK_STATES) else "unknown"
    tip = [round(v * 1e3, 1) for v in s.scope_tip_position_m]
    return (
        f"#{s.sequence} t={s.sim_time_s:.3f} s link={state} safe={s.safe_state} "
        f"in={s.valve_in_opening:.3f} out={s.valve_out_opening:.3f} "
        f"pump={s.pump_set_pressure_pa / PA_PER_MMHG:.1f} mmHg tip={tip} mm "
        f"cavity={s.cavity_pressure_pa / PA_PER_MMHG:.1f} mmHg deficit={s.deficit_m3 * 1e6:.1f} ml "
        f"alarms={s.alarm_bits:#x} latency p99={s.latency_p99_s * 1e3:.3f} ms"
    )


def open_service(node, builder_name, open_fn, deadline):
    """Opens a service, retrying while the daemon has not created it yet."""
    while True:
        try:
            return open_fn(node.service_builder(iox2.ServiceName.new(builder_name)))
        except iox2.PublishSubscribeOpenError as e:
            error = e
        except iox2.EventOpenError as e:
            error = e
        if time.monotonic() >= deadline:
            raise SystemExit(f"error: cannot open {builder_name} ({error!r}): is hydrometrad running with this prefix?")
        time.sleep(0.05)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--prefix", default="hydrometra/v1", help="service prefix (default hydrometra/v1)")
    parser.add_argument("--count", type=int, default=0, help="stop after this many statuses (0: run until Ctrl-C)")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the daemon / for data")
    parser.add_argument("--json", action="store_true", help="print one JSON object per status")
    args = parser.parse_args()
    prefix = args.prefix.rstrip("/")

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
    deadline = time.monotonic() + args.timeout
    status_service = open_service(node, f"{prefix}/status", lambda b: b.publish_subscribe(Status).open(), deadline)
    event_service = open_service(node, f"{prefix}/events", lambda b: b.event().open(), deadline)
    subscriber = status_service.subscriber_builder().create()
    listener = event_service.listener_builder().create()

    printed = 0
    last_data = time.monotonic()
    try:
        while args.count == 0 or printed < args.count:
            # Sleep until the daemon signals new data (or 100 ms pass), then drain the buffer.
            events = listener.timed_wait(iox2.Duration.from_millis(100))
            if any(e.id.as_value == EVENT_SHUTDOWN for e in events):
                print("daemon shutting down", file=sys.stderr)
            while args.count == 0 or printed < args.count:
                sample = subscriber.receive()
                if sample is None:
                    break
                status = sample.payload().contents
                print(json.dumps(as_dict(status)) if args.json else describe(status), flush=True)
                printed += 1
                last_data = time.monotonic()
            if time.monotonic() - last_data > args.timeout:
                print(f"error: no status for {args.timeout} s", file=sys.stderr)
                return 1
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
