#!/usr/bin/env python3
"""Read an MCAP file of `scip2can decode --mcap` with independent readers.

Usage: mcap_read.py rosbags|mcap FILE

- rosbags: the rosbags library (as a ROS 2 bag; it parses the ros2msg schemas itself).
- mcap: the mcap library with mcap-ros2-support (CDR by the ros2msg schema) and
  mcap-protobuf-support (protobuf by the file descriptor set in the schema).

Prints one JSON object per message, in file order: topic, schema, log_time (ns) and
the message's fields. Non-finite floats are written as the strings "nan", "inf",
"-inf" (JSON has no such numbers). Exits with status 3 and the missing module's name
on standard error when a library is not installed.
"""
import json
import math
import sys


def num(x):
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x


def stamp_ns(sec, nsec):
    return int(sec) * 1_000_000_000 + int(nsec)


def ros_scan(m):
    return {
        "stamp_ns": stamp_ns(m.header.stamp.sec, m.header.stamp.nanosec),
        "frame_id": m.header.frame_id,
        "angle_min": num(m.angle_min),
        "angle_max": num(m.angle_max),
        "angle_increment": num(m.angle_increment),
        "time_increment": num(m.time_increment),
        "scan_time": num(m.scan_time),
        "range_min": num(m.range_min),
        "range_max": num(m.range_max),
        "ranges": [num(r) for r in m.ranges],
        "intensities": [num(i) for i in m.intensities],
    }


def ros_diagnostics(m):
    return {
        "stamp_ns": stamp_ns(m.header.stamp.sec, m.header.stamp.nanosec),
        "status": [
            {
                "level": int(s.level[0] if isinstance(s.level, (bytes, bytearray)) else s.level),
                "name": s.name,
                "message": s.message,
                "hardware_id": s.hardware_id,
                "values": {kv.key: kv.value for kv in s.values},
            }
            for s in m.status
        ],
    }


def foxglove_scan(m):
    return {
        "stamp_ns": stamp_ns(m.timestamp.seconds, m.timestamp.nanos),
        "frame_id": m.frame_id,
        "pose": [
            m.pose.position.x,
            m.pose.position.y,
            m.pose.position.z,
            m.pose.orientation.x,
            m.pose.orientation.y,
            m.pose.orientation.z,
            m.pose.orientation.w,
        ],
        "start_angle": num(m.start_angle),
        "end_angle": num(m.end_angle),
        "ranges": [num(r) for r in m.ranges],
        "intensities": [num(i) for i in m.intensities],
    }


def convert(schema, m):
    if schema == "sensor_msgs/msg/LaserScan":
        return ros_scan(m)
    if schema == "diagnostic_msgs/msg/DiagnosticArray":
        return ros_diagnostics(m)
    if schema == "foxglove.LaserScan":
        return foxglove_scan(m)
    raise SystemExit(f"unexpected schema {schema}")


def with_rosbags(path):
    from pathlib import Path

    from rosbags.highlevel import AnyReader

    with AnyReader([Path(path)]) as reader:
        for conn, log_time, raw in reader.messages():
            m = reader.deserialize(raw, conn.msgtype)
            out = {"topic": conn.topic, "schema": conn.msgtype, "log_time": log_time}
            out.update(convert(conn.msgtype, m))
            print(json.dumps(out))


def with_mcap(path):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[Ros2Decoders(), ProtobufDecoders()])
        header = reader.get_header()
        for schema, channel, message, m in reader.iter_decoded_messages(log_time_order=False):
            out = {
                "topic": channel.topic,
                "schema": schema.name,
                "log_time": message.log_time,
                "profile": header.profile,
            }
            out.update(convert(schema.name, m))
            print(json.dumps(out))


def main():
    which, path = sys.argv[1], sys.argv[2]
    try:
        if which == "rosbags":
            with_rosbags(path)
        else:
            with_mcap(path)
    except ModuleNotFoundError as e:
        print(f"missing Python module: {e.name}", file=sys.stderr)
        sys.exit(3)


if __name__ == "__main__":
    main()
