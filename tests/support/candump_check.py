#!/usr/bin/env python3
"""Read a candump log with python-can and decode the fixed-layout frames with cantools.

Usage: candump_check.py <dbc> <candump log>
Prints one JSON object per frame: time, id, extended, fd, brs, data (hex), and, for
frames the DBC describes (node 0 of the default window), the message name and its raw
signals (no scaling, no value tables), so they compare exactly with the Rust decoder.
"""
import json
import sys

import can
import cantools


def main():
    db = cantools.database.load_file(sys.argv[1])
    known = {m.frame_id for m in db.messages}
    for msg in can.CanutilsLogReader(sys.argv[2]):
        out = {
            "time": msg.timestamp,
            "id": msg.arbitration_id,
            "extended": msg.is_extended_id,
            "fd": msg.is_fd,
            "brs": msg.bitrate_switch,
            "data": bytes(msg.data).hex(),
            "name": None,
            "signals": None,
        }
        # Data frames have a variable layout (bit-packed points): only their header is
        # in the DBC, so cantools decodes the fixed-layout frames only.
        if msg.arbitration_id in known and db.get_message_by_frame_id(msg.arbitration_id).name != "ScanData":
            m = db.get_message_by_frame_id(msg.arbitration_id)
            out["name"] = m.name
            out["signals"] = db.decode_message(
                msg.arbitration_id,
                bytes(msg.data),
                decode_choices=False,
                scaling=False,
                allow_truncated=True,
            )
        print(json.dumps(out))


if __name__ == "__main__":
    main()
