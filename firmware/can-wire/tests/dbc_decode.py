#!/usr/bin/env python3
"""Decode a candump log with scip2can.dbc using cantools; print one JSON object per frame.

Usage: dbc_decode.py <dbc> <candump log>
Log lines: "(<time>) <iface> <ID>#<hex data>" (classic) or "<ID>##<flags><hex data>" (FD).
Values are raw (no scaling, no value tables) so they compare exactly with the Rust decoder.
"""
import json
import sys

import cantools


def main():
    db = cantools.database.load_file(sys.argv[1])
    with open(sys.argv[2]) as log:
        for line in log:
            parts = line.split()
            if len(parts) != 3:
                continue
            ident, _, payload = parts[2].partition("#")
            if payload.startswith("#"):
                payload = payload[2:]  # FD: skip "#" and the flags nibble
            frame_id = int(ident, 16)
            data = bytes.fromhex(payload)
            msg = db.get_message_by_frame_id(frame_id)
            signals = db.decode_message(
                frame_id, data, decode_choices=False, scaling=False, allow_truncated=True
            )
            print(json.dumps({"id": frame_id, "name": msg.name, "signals": signals}))


if __name__ == "__main__":
    main()
