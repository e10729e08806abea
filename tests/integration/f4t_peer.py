#!/usr/bin/python3
"""A Watlow F4T and a probe module as an independent Modbus TCP peer (pymodbus 3.0).

Serves, on one port, unit 1 as an F4T with the register map and enumerations
of ESPEC North America's ChamberConnectLibrary (chamberconnectlibrary/
watlowf4t.py) and Watlow's F4T data map: loop 1 set point 2782 and process
value 2820 (IEEE float, low word first), alarm 1 state 1356 (None = 61),
the units of values served over Modbus TCP 6730 (°F = 30, °C = 15), ramp
action 2794 (Off = 62), ramp scale 2796 (Minutes = 57), ramp rate 2798.
Only those addresses exist (a sparse block: any other answers exception 2).
Temperatures are served in the units the units register names.

Unit 2 is a probe module: input registers 0 and 1, int16, °C x 10.

A pty stands in for the gyro line (nothing is sent on it). Once the port
accepts connections, the endpoints file gyrothermd reads ([simulator]
endpoints_file) is written. SIGUSR1 raises alarm 1 (Alarm High, 7).

Usage: f4t_peer.py PORT ENDPOINTS_FILE [--units F|C] [--pv-c 25.0] [--probe-c 25.0]
"""

import argparse
import os
import signal
import socket
import struct
import threading
import time

from pymodbus.datastore import (ModbusServerContext, ModbusSlaveContext,
                                ModbusSparseDataBlock)
from pymodbus.server import StartTcpServer

UNITS = {"C": 15, "F": 30}


def float_words(value):
    """IEEE float, low word at the lower address (the F4T's order)."""
    bits = struct.unpack(">I", struct.pack(">f", value))[0]
    return [bits & 0xFFFF, bits >> 16]


def int16_word(value):
    return struct.unpack(">H", struct.pack(">h", value))[0]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("endpoints_file")
    parser.add_argument("--units", choices=sorted(UNITS), default="F")
    parser.add_argument("--pv-c", type=float, default=25.0)
    parser.add_argument("--probe-c", type=float, default=25.0)
    args = parser.parse_args()

    def served(celsius):
        return celsius * 1.8 + 32.0 if args.units == "F" else celsius

    holding = {}
    for address, words in ((2782, float_words(0.0)),  # set point: 0 until written
                           (2820, float_words(served(args.pv_c))),
                           (2798, float_words(1.0))):
        holding[address] = words[0]
        holding[address + 1] = words[1]
    holding[1356] = 61  # alarm 1 state: None
    holding[6730] = UNITS[args.units]
    holding[2794] = 62  # ramp action: Off
    holding[2796] = 57  # ramp scale: Minutes
    f4t = ModbusSlaveContext(hr=ModbusSparseDataBlock(holding), zero_mode=True)
    raw = int16_word(round(args.probe_c * 10))
    probes = ModbusSlaveContext(ir=ModbusSparseDataBlock({0: raw, 1: raw}), zero_mode=True)
    context = ModbusServerContext(slaves={1: f4t, 2: probes}, single=False)

    def raise_alarm(_signum, _frame):
        f4t.setValues(3, 1356, [7])  # Alarm High

    signal.signal(signal.SIGUSR1, raise_alarm)

    master, slave = os.openpty()
    gyro_device = os.ttyname(slave)

    def announce():
        while True:
            try:
                with socket.create_connection(("127.0.0.1", args.port), timeout=0.2):
                    break
            except OSError:
                time.sleep(0.02)
        tmp = args.endpoints_file + ".tmp"
        with open(tmp, "w") as f:
            f.write('modbus_host = "127.0.0.1"\n')
            f.write("modbus_port = %d\n" % args.port)
            f.write('gyro_device = "%s"\n' % gyro_device)
            f.write("pid = %d\n" % os.getpid())
        os.rename(tmp, args.endpoints_file)

    threading.Thread(target=announce, daemon=True).start()
    StartTcpServer(context=context, address=("127.0.0.1", args.port))
    os.close(master)


if __name__ == "__main__":
    main()
